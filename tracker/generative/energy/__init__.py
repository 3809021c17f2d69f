"""The terms of the generative fit's energy, one module each (thesis ch. 6).

Every term returns :class:`Residuals`: weighted residuals whose squares add up to the
term's energy and their Jacobian by the 26 unknowns of :mod:`tracker.generative.model`
(and, while a user's hand proportions are estimated, by the 7 proportions); the
terms whose Jacobian costs time compute it when first asked for
(:meth:`Residuals.deferred`), which the solver does only where it linearises.
:mod:`tracker.generative.fit` stacks them; :mod:`tracker.generative.solver` minimises
the sum.

| module | term |
|---|---|
| :mod:`.data` | glove points to the model surface of their color (point-to-plane) |
| :mod:`.silhouette` | model outside the hand or in front of the depth (occlusions) |
| :mod:`.prior` | Gaussian posture prior learned from the project's natural postures |
| :mod:`.reference` | unseen joints keep the start's angles; joints an object hides are held |
| :mod:`.limits` | joint limits |
| :mod:`.collision` | fingers that pass into each other |
| :mod:`.temporal` | closeness to the previous frame |
| :mod:`.fingertips` | fingertip detections named by Eq. 11 (Tzionas et al. 2014) |
"""
