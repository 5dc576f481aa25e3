"""Drive the physics-based face model with a contraction time series and render it,
on the generic face or personalised to the analysed subject."""
