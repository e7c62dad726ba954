"""Estimators: OLS/WLS, IDIM, essential parameters, DIDIM, the Projection Method, maximum likelihood, friction, standard sets."""
