"""Dense optical flow on the face: flow in the head's frame on a fixed grid
(:mod:`.dense`), the face model's flow templates per muscle and expression
(:mod:`.templates`) and expression recognition by template matching
(:mod:`.recognition`)."""
