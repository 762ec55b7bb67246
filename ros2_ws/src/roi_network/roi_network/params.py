"""ROS 2 params files as a node gets them: one helper for the nodes' offline readers
(rover_vo's ``--params``) and the launcher's checks (``globloc run``)."""

from __future__ import annotations

from typing import Any


def flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested parameter mappings as dotted names, as ROS does
    (``features: {stereo_sync_tolerance_s: ...}`` -> ``features.stereo_sync_tolerance_s``)."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def node_parameters(doc: Any, node_name: str) -> dict[str, Any]:
    """The flattened ``ros__parameters`` a parsed params file ``doc`` gives node
    ``node_name``: those under ``/**``, then under the node's name with and without its
    leading slash, each over the ones before. Empty when ``doc`` is not a mapping."""
    if not isinstance(doc, dict):
        return {}
    bare = node_name.lstrip("/")
    out: dict[str, Any] = {}
    for key in ("/**", bare, "/" + bare):
        section = doc.get(key)
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            out.update(flatten(section["ros__parameters"]))
    return out
