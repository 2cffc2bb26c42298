"""ROS 2 names: what a fully qualified topic, a namespace and a node name may be (the rules of
rmw's `rmw_validate_full_topic_name`, `rmw_validate_namespace` and `rmw_validate_node_name`),
each problem said with its fix."""

from __future__ import annotations

import re

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_NODE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MAX_TOPIC = 255  # rmw's limit on a topic name, less the room its DDS prefix takes; plenty here


def name_problem(name: str, what: str = "topic") -> str | None:
    """Why `name` is not a fully qualified ROS 2 topic name or namespace ('/' alone is the
    root namespace), or None."""
    if not name.startswith("/"):
        also = name_problem("/" + name, what)
        head = f"{what} {name!r} must be absolute (start with '/')"
        return f"{head}; and as '/{name}': {also}" if also else f"{head}: e.g. '/{name}'"
    if name == "/":
        return None if what == "namespace" else f"{what} '/' names nothing; e.g. '/imu/data'"
    if name.endswith("/"):
        return f"{what} {name!r} must not end with '/': {name.rstrip('/')!r}"
    if "//" in name:
        return f"{what} {name!r} has an empty part ('//'): {re.sub('/+', '/', name)!r}"
    if len(name) > MAX_TOPIC:
        return f"{what} {name!r} is {len(name)} characters; ROS 2 allows {MAX_TOPIC}"
    for token in name[1:].split("/"):
        if not _TOKEN.match(token):
            if token[:1].isdigit():
                return f"{what} {name!r}: part {token!r} starts with a digit, which ROS 2 refuses"
            bad = sorted({c for c in token if not (c.isascii() and (c.isalnum() or c == "_"))})
            return (
                f"{what} {name!r}: part {token!r} has {''.join(bad)!r}; ROS 2 names take only "
                "letters, digits and '_'"
            )
    return None


def node_problem(name: str) -> str | None:
    """Why `name` is not a ROS 2 node name, or None."""
    if not _NODE.match(name):
        return (
            f"node name {name!r} must be letters, digits and '_', not starting with a digit "
            "(e.g. 'imud')"
        )
    return None


def join(*parts: str) -> str:
    """Namespace and relative names joined into one absolute name: join('/', 'imu0', 'imu/data')
    is '/imu0/imu/data'."""
    return "/" + "/".join(p.strip("/") for p in parts if p.strip("/"))
