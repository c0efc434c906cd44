"""The int8 artifact format's one owner. An artifact directory (``jnds export``, ``jnds
calibrate``) holds ONNX graphs and ``manifest.json``; docs/artifact-format.md describes it.

- ``manifest``: ``Manifest``, the directory's ``manifest.json`` (read, validated, written),
  and which file serves a graph at a precision (``Manifest.choose``);
- ``layouts``: the layouts of an int8 network graph's u8 edges, kept in the graph's own
  metadata (``InputsLayout``, ``HeadLayout``, ``BlockLayout``).

Written by ``export`` and ``calibration``, read by ``runtime``; this package imports
neither.
"""

from .layouts import (
    BLOCK_KEY,
    HEAD,
    HEAD_KEY,
    INPUTS,
    INPUTS_KEY,
    LEVELS_KEY,
    BlockLayout,
    Cut,
    HeadLayout,
    InputsLayout,
    levels_of_session,
    levels_to_json,
    preprocess,
)
from .manifest import (
    ACTIVATION_TYPES,
    FORMAT,
    GROUPS,
    MANIFEST,
    READABLE,
    Block,
    Edge,
    Graph,
    GraphChoice,
    Int8Graph,
    Manifest,
    Variant,
    file_hash,
    variant_key,
    write_json,
)

__all__ = [
    "ACTIVATION_TYPES",
    "BLOCK_KEY",
    "FORMAT",
    "GROUPS",
    "HEAD",
    "HEAD_KEY",
    "INPUTS",
    "INPUTS_KEY",
    "LEVELS_KEY",
    "MANIFEST",
    "READABLE",
    "Block",
    "BlockLayout",
    "Cut",
    "Edge",
    "Graph",
    "GraphChoice",
    "HeadLayout",
    "InputsLayout",
    "Int8Graph",
    "Manifest",
    "Variant",
    "file_hash",
    "levels_of_session",
    "levels_to_json",
    "preprocess",
    "variant_key",
    "write_json",
]
