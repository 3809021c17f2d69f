"""The generative stage: fit the articulated hand the camera sees (thesis ch. 5-6).

The database lookup initialises and recovers; this stage gives the answer. Files:

- :mod:`.model`: the hand's unknowns, its posed surface samples and their Jacobians;
- :mod:`.observation`: what one frame shows (glove points, hand mask, depth);
- :mod:`.energy`: one module per energy term;
- :mod:`.solver`: Levenberg-Marquardt;
- :mod:`.fit`: the summed energy of one frame, and the hand proportions' estimate;
- :mod:`.visibility`: which keypoints the camera sees.

:class:`tracker.pipeline.Tracker` runs it frame after frame.
"""
