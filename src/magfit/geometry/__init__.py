"""The model geometry shared by the methods and the diagnostics, below both.

- :mod:`.quadric`: fitted quadric coefficients (eq. 3-4) -> ellipsoid centre and shape -> Calibration.
- :mod:`.frame`: normalised frames, the residuals and distances to an ellipsoid and their Jacobians for
  the three nested models (sphere, diag, full), the first-order maximum-likelihood fit.
- :mod:`.cells`: the equal-area partition of the sphere of directions.

Nothing here imports :mod:`magfit.methods` or :mod:`magfit.diagnostics`.
"""
