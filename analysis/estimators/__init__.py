"""Estimators: OLS/WLS, IDIM, essential parameters, DIDIM, the Projection Method, maximum likelihood, gravity tilt, physically consistent and standard sets, the streamed reduction."""
