"""The analysis of a video: :func:`.pipeline.analyze` (track, calibrate, estimate, check
the fit) and its result, :class:`.results.Analysis`, with the output folder it writes."""
