"""From logs and a model to numbers: the immutable problem, the least-squares solvers and fit,
identifiability, model comparison, the likelihood and priors, and the emcee posterior with its chain
file and convergence rules."""
