"""Errors that mean "the user's input is wrong": the CLI prints them as one line and exits 2."""


class UserError(Exception):
    """Bad input (file, field, value): message names what, where and what was expected."""


class SimulatorError(RuntimeError):
    """The simulator failed or died mid-run; message names the scenario and seed."""
