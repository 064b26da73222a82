"""The error a bad effect, or a bad file of effects, raises: apart from `rig.models` so that every command can
catch it (`rig.cli.main`) without loading the models, their scipy and numba."""


class EffectFileError(ValueError):
    """An effect, or a file of effects, that cannot be used (a bad definition, a name taken twice); the message
    names the effect, where it comes from, and the fix, in one line."""
