"""Input and output: video reading (:mod:`.video`), the contractions table and its
columns (:mod:`.table`), output folders, atomic files and the one list of output file
names (:mod:`.outputs`), ``analysis.json`` (:mod:`.report`) and the on-disk cache
(:mod:`.cache`). Files and videos are written by :mod:`synth.files` and
:class:`synth.render.video.VideoWriter`. The lowest layer of :mod:`faceanalysis`: it
imports nothing else from it."""
