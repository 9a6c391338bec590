"""The disturbance sources' registry (``ground.sources`` fills it; a source that plays another, the wheel jitter
over its ``--jitter-base``, looks that one up here, so neither module imports the other)."""

SOURCES = {}


def register_source(name, factory):
    """Register a source class (``add_arguments``, ``from_args``) under ``name``."""
    if name in SOURCES:
        raise ValueError("source %r already registered" % name)
    SOURCES[name] = factory


def get_source(name):
    try:
        return SOURCES[name]
    except KeyError:
        raise ValueError("unknown source %r (known: %s)" % (name, ", ".join(sorted(SOURCES)))) from None
