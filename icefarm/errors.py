"""The one exception type the command line turns into a clean one-line error."""


class InputError(ValueError):
    """Bad user input (a parameter, a mesh, a manifest): the message says what and how to fix it."""
