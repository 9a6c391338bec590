"""Under MicroPython and CPython alike: a deep copy of a JSON document and a change at a dotted key path ("x.jrw",
"wheels.axes.0"), with ``DELETE`` to remove the key; the checkers' scripts apply their bad cases with them."""

DELETE = object()


def copy(v):
    if isinstance(v, dict):
        return dict((k, copy(v[k])) for k in v)
    if isinstance(v, list):
        return [copy(x) for x in v]
    return v


def put(d, path, value):
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    last = keys[-1]
    if value is DELETE:
        del d[last]
    elif isinstance(d, list):
        d[int(last)] = value
    else:
        d[last] = value
