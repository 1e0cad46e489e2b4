"""simharness: closed-loop evaluation of trajectory predictors in dense heterogeneous traffic."""

__version__ = "0.1.0"
