"""Bayesian posterior by ensemble MCMC (emcee) and its convergence diagnostics."""
