"""A particle filter whose likelihood is a discriminative correlation filter learnt online."""
