"""Input and output: video reading (:mod:`.video`), the contractions table and its
columns (:mod:`.table`), output folders and atomic files (:mod:`.outputs`),
``analysis.json`` (:mod:`.report`), the on-disk cache (:mod:`.cache`) and the overlay
video writer (:mod:`.video_writer`). The lowest layer of :mod:`faceanalysis`: it imports
nothing else from it."""
