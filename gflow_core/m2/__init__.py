"""Metric Mixture (M2) tracking with exemplars in a metric space (Toyama & Blake, IJCV 2002).

Modules
-------
chamfer     sampling a chamfer image along curves: the chamfer distance of eq. 5.
dynamics    p(X_t | X_{t-1}): a Markov matrix over exemplars and an AR(1) process on alpha (sec. 4.3).
tracking    the particle filter over X = (alpha, k): proposal by the dynamics, weights by eq. 7.
"""
