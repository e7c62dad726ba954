"""Statistical checks: validation on held-out data, residual analysis, noise PDF tests."""
