"""The artifact directory's ``manifest.json``: ``Manifest`` reads, validates and writes it.

``jnds export`` writes a directory of ONNX graphs and a manifest that says everything a
runtime needs; ``jnds calibrate`` adds int8 graphs to it; the runtime, ``jnds run`` and
the benchmarks read it. All of them go through ``Manifest``: ``Manifest.load`` validates
a directory's manifest, ``save`` writes it atomically, ``choose`` says which file serves
a graph at a precision, with which pruned variants. docs/artifact-format.md describes
every field.

Graphs (``export/__init__`` describes their inputs and outputs):
- ``network``: input block + feature extractor + output block at native resolution;
- ``upsample``: the upsample block's kernel prediction (absent when scale is 1).
Each has fp32 ``file``, pruned ``variants`` (``export.prune``: without a filter path's
kernels or the upsample features) and per calibration method an ``int8`` entry with its
own variants. ``int8_method`` is the calibration the runtime's int8 uses by default (the
last calibrated). An int8 entry's ``inputs``, ``head``, ``levels`` (``Edge``) and
``block`` (``Block``) say whether its network graph takes and gives float NCHW tensors,
as the fp32 graphs do, or u8 ones whose layouts are in the graph's metadata
(``artifacts.layouts``; ``runtime.network`` runs either from float feeds).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

from ..errors import ArtifactError
from ..layout import UPSAMPLE_ROOTS

# 2: the upsample kernel in phase layout at native resolution; 3: an int8 entry's
# ``inputs``, ``head``, ``levels`` and ``block`` as the values of ``Edge`` and ``Block``
# (2 wrote a sentence; ``_from_v2`` reads them)
FORMAT = "jnds-artifacts/3"
READABLE = (FORMAT, "jnds-artifacts/2")
MANIFEST = "manifest.json"
ACTIVATION_TYPES = ("u8", "s8")


class Edge(str, Enum):
    """How an int8 network graph gives one of its edges: as the fp32 graph does (float
    tensors), or as u8 tensors whose layout is in the graph's metadata
    (``artifacts.layouts``)."""

    FLOAT = "float"
    U8 = "u8"

    def __str__(self) -> str:
        return self.value


class Block(str, Enum):
    """Where an int8 network graph's upsamplings and concatenations (the decoder blocks',
    the output block's) run: in the graph, or between runs of its segments, where the
    runtime makes each cut's entry (``artifacts.layouts.BlockLayout``)."""

    GRAPH = "graph"
    CUT = "cut"

    def __str__(self) -> str:
        return self.value


# what the runtime must do around the graphs, written for a reader of the manifest
DESCRIPTION = {
    "pad_mode": "replicate the last row/column up to a multiple, crop the output back",
    "layout": "NCHW float32",
    "tonemap": "inside network.onnx and upsample.onnx: x' = log(clamp(x, 0, 65535) + 1)^(1/2.2)",
    "kernel_order": "row-major 3x3 taps (dy, dx) from (-1, -1) to (1, 1); borders replicate",
}
FILTER_PATHS = {
    "diffuse/specular": "spatiotemporal(spatial, temporal, blend) at native; level k (native / 2^k): "
    "2x2 average pool then 'down' kernel; back up: bilinear x2, 'up' kernel, "
    "lerp(skip, filtered, up_blend); ReLU after every filter; native up kernel "
    "and up_blend are '<path>.up', '<path>.up_blend'",
    "albedo/normal": "spatiotemporal with the shared 'aux.*' kernels; normals filtered as n * 0.5 + 0.5",
    "blend": "lerp(current, history, blend): 1 = all history",
    "history": "next frame's history = [diffuse, specular, albedo, normal] filtered, warped bicubically "
    "along the motion vectors; on a first frame or cut the current inputs stand in",
}


def file_hash(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


# the network outputs' groups a pruned variant can drop (export.prune); here so that the
# runtime names variants without importing export.prune's onnx (its cold start)
GROUPS = ("diffuse", "specular", "features")


def variant_key(drops) -> str:
    """'no-diffuse', 'no-diffuse-features', ...: the name of a set of dropped groups."""
    return "no-" + "-".join(g for g in GROUPS if g in set(drops))


@dataclass
class Variant:
    """A pruned graph: ``drops`` are the output groups it does not compute."""

    file: str
    drops: list[str]
    outputs: list[str]
    sha256: str = ""


@dataclass
class Int8Graph:
    file: str
    sha256: str
    activation_type: str  # ACTIVATION_TYPES
    weights: str  # how the weights are quantized, for a reader
    op_types: list[str]
    float_nodes: list[str]
    ranges: str  # calibration.<method>.json: scale and zero point of every quantized tensor
    variants: dict[str, Variant] = field(default_factory=dict)
    # the output block's head: float outputs, or one u8 tensor ``head`` (HEAD_KEY, calibration.head)
    head: Edge = Edge.FLOAT
    # current and history (and the guide albedo): float, or one u8 tensor ``inputs``
    # preprocessed (INPUTS_KEY, calibration.inputs)
    inputs: Edge = Edge.FLOAT
    # the upsamplings and concatenations: in the graph, or cut (BLOCK_KEY, calibration.block)
    block: Block = Block.GRAPH
    # the feature extractor's level heads: float outputs, or one u8 tensor each (LEVELS_KEY,
    # calibration.head_ranges.code_levels)
    levels: Edge = Edge.FLOAT

    @classmethod
    def from_dict(cls, d: dict, where: str) -> Int8Graph:
        """The entry from its JSON object; ``where`` names it in an error."""
        d = dict(d)
        for key, kind in (("head", Edge), ("inputs", Edge), ("levels", Edge), ("block", Block)):
            if key in d:
                d[key] = _member(kind, d[key], f"{where}.{key}")
        if d.get("activation_type") not in ACTIVATION_TYPES:
            raise ArtifactError(
                f"{where}.activation_type is {d.get('activation_type')!r}, expected one of "
                f"{', '.join(map(repr, ACTIVATION_TYPES))}"
            )
        variants = {k: Variant(**v) for k, v in d.pop("variants", {}).items()}
        return cls(**d, variants=variants)


def _member(kind: type[Enum], value, where: str):
    """``kind(value)``, or ArtifactError naming the field, the value and the expected ones."""
    try:
        return kind(value)
    except ValueError:
        raise ArtifactError(f"{where} is {value!r}, expected one of {', '.join(repr(m.value) for m in kind)}") from None


@dataclass
class Graph:
    file: str
    inputs: dict
    outputs: dict
    precision: str = "fp32"
    resolution: str = "native"
    sha256: str = ""
    variants: dict[str, Variant] = field(default_factory=dict)
    int8: dict[str, Int8Graph] = field(default_factory=dict)


@dataclass
class GraphChoice:
    """The files that serve one graph in one configuration: ``variants`` maps the output
    groups a file drops (a frozenset; empty for the full graph) to its path."""

    path: Path
    precision: str
    variants: dict[frozenset, Path]


@dataclass
class Manifest:
    checkpoint: dict  # {path, sha256} of the checkpoint exported
    model_config: dict  # model.ModelConfig fields
    pad_multiple: int  # native sizes must be multiples of this (the runtime pads)
    graphs: dict[str, Graph]
    validation: list[dict] = field(default_factory=list)  # export's ONNX Runtime vs PyTorch rows
    qat_ranges: str = "qat_ranges.json"  # the ranges learned in QAT, per graph and tensor
    int8_method: str | None = None
    int8_validation: dict[str, list[dict]] = field(default_factory=dict)
    format: str = FORMAT
    package_version: str = ""
    # model_config.upsample_width 0: the one learned 3x3 kernel (9 taps, clamped) the
    # upsample filter applies at every target pixel; there is no upsample graph
    upsample_kernel: list[float] | None = None

    @property
    def scale(self) -> int:
        return int(self.model_config.get("scale", 2))

    @property
    def filter_levels(self) -> int:
        return int(self.model_config["filter_levels"])

    @property
    def upsample_root(self) -> int:
        # artifacts of checkpoints from before it was a choice have no entry: linear
        return self.model_config.get("upsample_root", 1)

    @property
    def firefly_clamp(self) -> float:
        # model.ModelConfig.firefly_clamp; artifacts from before it existed: off
        return float(self.model_config.get("firefly_clamp", 0.0))

    @property
    def diffuse_fill(self) -> bool:
        # model.ModelConfig.diffuse_fill; artifacts from before it existed: off
        return bool(self.model_config.get("diffuse_fill", False))

    @property
    def albedo_at_holes(self) -> bool:
        # model.ModelConfig.albedo_at_holes; artifacts from before it existed: off
        return bool(self.model_config.get("albedo_at_holes", False))

    @property
    def guide_albedo(self) -> bool:
        # model.ModelConfig.guide_albedo: the network graph's third input ``guide``; artifacts
        # from before it existed: none
        return bool(self.model_config.get("guide_albedo", False))

    # -- files ---------------------------------------------------------------------------

    @classmethod
    def load(cls, root: str | Path) -> Manifest:
        """The manifest of artifact directory ``root``, validated (ArtifactError names the
        file and the problem)."""
        path = Path(root) / MANIFEST
        if not path.is_file():
            raise ArtifactError(f"{path}: missing; run `jnds export --out {root}` first")
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ArtifactError(f"{path}: unreadable ({exc})") from exc
        if not isinstance(data, dict) or data.get("format") not in READABLE:
            got = data.get("format") if isinstance(data, dict) else None
            raise ArtifactError(
                f"{path}: format {got!r}, expected {FORMAT!r}; "
                "re-run `jnds export` (and `jnds calibrate`) with this version"
            )
        try:
            manifest = cls.from_dict(data)
        except (KeyError, TypeError, AttributeError) as exc:
            raise ArtifactError(f"{path}: malformed manifest ({exc!r})") from exc
        except ArtifactError as exc:
            raise ArtifactError(f"{path}: {exc}") from exc
        if manifest.upsample_root not in UPSAMPLE_ROOTS:
            raise ArtifactError(
                f"{path}: model_config.upsample_root is {manifest.upsample_root!r}, "
                f"expected one of {', '.join(map(str, UPSAMPLE_ROOTS))}"
            )
        if "network" not in manifest.graphs:
            raise ArtifactError(f"{path}: no 'network' graph")
        if manifest.scale > 1 and "upsample" not in manifest.graphs:
            k = manifest.upsample_kernel
            if not (
                isinstance(k, list) and len(k) == 9 and all(isinstance(v, (int, float)) and -1 <= v <= 1 for v in k)
            ):
                raise ArtifactError(
                    f"{path}: no 'upsample' graph, and upsample_kernel is {k!r}, expected 9 numbers in [-1, 1]"
                )
        return manifest

    def save(self, root: str | Path) -> Path:
        path = Path(root) / MANIFEST
        write_json(path, self.to_dict())
        return path

    @classmethod
    def from_dict(cls, data: dict) -> Manifest:
        """The manifest from its JSON object, in any ``READABLE`` format (read as
        ``FORMAT``: ``save`` writes it so); ArtifactError names a field of the wrong type."""
        if data["format"] not in READABLE:
            raise ArtifactError(f"format {data['format']!r}, expected {FORMAT!r}")
        if data["format"] != FORMAT:
            data = _from_v2(data)

        def variants(d):
            return {k: Variant(**v) for k, v in d.get("variants", {}).items()}

        graphs = {}
        for name, g in data["graphs"].items():
            int8 = {m: Int8Graph.from_dict(e, f"graphs.{name}.int8.{m}") for m, e in g.get("int8", {}).items()}
            graphs[name] = Graph(
                file=g["file"],
                inputs=g.get("inputs", {}),
                outputs=g.get("outputs", {}),
                precision=g.get("precision", "fp32"),
                resolution=g.get("resolution", "native"),
                sha256=g.get("sha256", ""),
                variants=variants(g),
                int8=int8,
            )
        method = data.get("int8_method")
        if method is not None and not any(method in g.int8 for g in graphs.values()):
            raise ArtifactError(f"int8_method is {method!r}, and no graph has an int8 entry of that name")
        return cls(
            checkpoint=data["checkpoint"],
            model_config=data["model_config"],
            pad_multiple=int(data["pad_multiple"]),
            graphs=graphs,
            validation=data.get("validation", []),
            qat_ranges=data.get("qat_ranges", "qat_ranges.json"),
            int8_method=method,
            int8_validation=data.get("int8_validation", {}),
            package_version=data.get("package_version", ""),
            upsample_kernel=data.get("upsample_kernel"),
        )

    def to_dict(self) -> dict:
        return {
            "format": self.format,
            "package_version": self.package_version,
            "checkpoint": self.checkpoint,
            "model_config": self.model_config,
            "scale": self.scale,
            "pad_multiple": self.pad_multiple,
            **DESCRIPTION,
            "filter_paths": {"levels": self.filter_levels, **FILTER_PATHS},
            "graphs": {k: asdict(g) for k, g in self.graphs.items()},
            "qat_ranges": self.qat_ranges,
            "validation": self.validation,
            "int8_method": self.int8_method,
            "int8_validation": self.int8_validation,
            **({"upsample_kernel": self.upsample_kernel} if self.upsample_kernel is not None else {}),
        }

    # -- which file serves what ------------------------------------------------------------

    def choose(self, root: str | Path, name: str, precision: str, method: str | None = None) -> GraphChoice:
        """The files of graph ``name`` at ``precision`` (int8: calibration ``method``,
        default ``int8_method``), checked to exist, with their pruned variants on disk."""
        root = Path(root)
        g = self.graphs[name]
        if precision == "fp32":
            file, variants = g.file, g.variants
        else:
            entry = g.int8.get(method or self.int8_method or "")
            if entry is None:
                what = f"int8 ({method})" if method else "int8"
                raise ArtifactError(f"{root}: no {what} graph for {name!r}; run `jnds calibrate`")
            file, variants = entry.file, entry.variants
        if not (root / file).is_file():
            raise ArtifactError(
                f"{root / file}: missing; re-run `jnds export`"
                + (" and `jnds calibrate`" if precision == "int8" else "")
            )
        found = {frozenset(): root / file}
        for v in variants.values():
            if (root / v.file).is_file():
                found[frozenset(v.drops)] = root / v.file
        return GraphChoice(root / file, precision, found)


def _from_v2(data: dict) -> dict:
    """A ``jnds-artifacts/2`` manifest as ``FORMAT``'s: its int8 entries' ``inputs``,
    ``head``, ``levels`` and ``block`` were sentences, "float" or "u8, ..." and "in the
    graph" or "between ...", and are ``Edge`` and ``Block`` values now."""

    def edge(v):
        return Edge.U8.value if isinstance(v, str) and v.startswith("u8") else v

    def block(v):
        if v == "in the graph":
            return Block.GRAPH.value
        return Block.CUT.value if isinstance(v, str) and v.startswith("between") else v

    graphs = {}
    for name, g in data["graphs"].items():
        int8 = {}
        for m, e in g.get("int8", {}).items():
            e = dict(e)
            for key in ("inputs", "head", "levels"):
                if key in e:
                    e[key] = edge(e[key])
            if "block" in e:
                e["block"] = block(e["block"])
            int8[m] = e
        graphs[name] = {**g, "int8": int8}
    return {**data, "graphs": graphs, "format": FORMAT}


def write_json(path: Path, data) -> None:
    """``data`` as JSON at ``path``, atomically (a reader never sees half a file)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)
