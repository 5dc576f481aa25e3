"""The output file names, and the atomic writers the toolkit writes them with."""

import synth.files
from faceanalysis.io import outputs


def test_the_writers_are_synths_one_atomic_writer():
    for name in ("atomic_path", "prepare_output_dir", "write_text_atomic", "write_bytes_atomic"):
        assert getattr(outputs, name) is getattr(synth.files, name)


def test_every_output_name_is_distinct_and_a_plain_file_name():
    names = [v for k, v in vars(outputs).items() if k.isupper() and isinstance(v, str)]
    assert len(names) == len(set(names)) >= 11
    assert all("/" not in n and "." in n for n in names)


def test_an_analysis_folder_uses_the_names(tmp_path):
    from faceanalysis.analysis.results import OutputFolder
    from faceanalysis.io.table import empty_table

    paths = OutputFolder(tmp_path / "run").write(empty_table(2, timestamps=[0, 0.04]), {})
    assert {p.name for p in paths.values()} == {outputs.CONTRACTIONS_CSV, outputs.ANALYSIS_JSON,
                                                 outputs.CONTRACTIONS_PNG}
