"""socdiff: forecasting how groups of people move together (Social Diffusion, Tanke et al.,
ICCV 2023), from Python.

The same engine as the ``socdiff`` command line, with numpy arrays where it has scenes:
positions are ``float32`` arrays ``[frames, persons, joints, 3]`` in metres, z up.

Example (MuPoTS-3D's test scenes onto the bundled model's 15 joints)::

    import socdiff
    model = socdiff.Model.load("models/groups-mrt15/model.safetensors")
    scene = socdiff.load_dataset("../shared/data/mupots3d").split("test")[0]
    samples, provenance = model.forecast(scene.positions, skeleton=scene.skeleton, observe=30, horizon=90, samples=8)
    samples.shape   # (8, 120, 3, 15, 3): K, observe + horizon frames, persons, joints, xyz
"""

from __future__ import annotations

import json
import os
import sys
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, NamedTuple, Optional, Sequence as Seq, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import _native, metrics

__all__ = [
    "Dataset",
    "Forecast",
    "Model",
    "Sequence",
    "Skeleton",
    "Stream",
    "TrainEvent",
    "evaluate",
    "load_dataset",
    "metrics",
    "save_dataset",
    "skeleton_names",
    "train",
]

__version__: str = _native.__version__

if threading.current_thread() is threading.main_thread():
    # The engine's workers include the interpreter's main thread, as the CLI's include its own.
    _native.start_workers()

PathLike = Union[str, "os.PathLike[str]"]
FloatArray = npt.NDArray[np.float32]
TrainEvent = Dict[str, Any]
"""A training event given to ``train``'s progress callback: ``{"kind": "started" | "step" |
"validation" | "saved" | "notice", ...}``; a step has ``step``, ``loss``, ``lr`` and
``seconds``."""


def _positions(positions: npt.ArrayLike, what: str = "positions") -> FloatArray:
    """``positions`` as a C-contiguous float32 array (a copy only when needed)."""
    try:
        array = np.ascontiguousarray(positions, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: cannot be read as float32 numbers ({e})") from None
    return array


def _path(p: PathLike) -> str:
    return os.fspath(p)


@dataclass(frozen=True)
class Skeleton:
    """A joint layout: joint names, bones as (parent, child) indices, and the left and right
    joints (the hips) that define a person's body frame."""

    name: str
    joints: List[str]
    bones: List[Tuple[int, int]] = field(default_factory=list)
    left: int = 0
    right: int = 0

    @staticmethod
    def named(name: str) -> "Skeleton":
        """A named skeleton: mupots17, mrt15, h36m17, smpl22, smpl24, panoptic19, bandai21,
        cmu31 (:func:`skeleton_names`)."""
        return Skeleton._from_native(_native.skeleton(name))

    @staticmethod
    def from_joint_names(joints: Seq[str], name: str = "custom") -> "Skeleton":
        """A layout known by its joint names only (no bones); the body frame is the joints named
        ``left_hip`` and ``right_hip`` when present (else the first two). Mapped onto a model's
        skeleton by name."""
        names = list(joints)
        left = names.index("left_hip") if "left_hip" in names else 0
        right = names.index("right_hip") if "right_hip" in names else 1 if left != 1 else 0
        return Skeleton(name, names, [], left, right)

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @staticmethod
    def _from_native(t: Tuple[str, List[str], List[Tuple[int, int]], int, int]) -> "Skeleton":
        name, joints, bones, left, right = t
        return Skeleton(name, list(joints), [(int(a), int(b)) for a, b in bones], left, right)

    def _native(self) -> Tuple[str, List[str], List[Tuple[int, int]], int, int]:
        return (self.name, list(self.joints), list(self.bones), self.left, self.right)


def skeleton_names() -> List[str]:
    """The names :meth:`Skeleton.named` knows."""
    return list(_native.skeleton_names())


@dataclass
class Sequence:
    """One recorded scene of a dataset."""

    name: str
    split: str
    """``train``, ``test`` or ``validation``."""
    fps: float
    skeleton: Skeleton
    positions: FloatArray
    """``[frames, persons, joints, 3]``, metres, z up."""
    valid: Optional[npt.NDArray[np.bool_]] = None
    """``[frames, persons]``: False where a person is not tracked (None: all valid)."""
    signals: Dict[str, FloatArray] = field(default_factory=dict)
    """Named per-(frame, person) signals ``[frames, persons]`` (e.g. ``speaking``)."""
    persons: List[Tuple[str, Optional[str]]] = field(default_factory=list)
    """(id, role) of each person (default: ids ``"0"``, ``"1"``, …)."""
    metadata: Dict[str, Any] = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def num_persons(self) -> int:
        return int(self.positions.shape[1])


@dataclass
class Dataset:
    """Named sequences with splits, one skeleton (a socdiff dataset directory)."""

    name: str
    sequences: List[Sequence]
    metadata: Dict[str, Any] = field(default_factory=dict)

    def split(self, split: str) -> List[Sequence]:
        """The sequences of one split."""
        return [s for s in self.sequences if s.split == split]

    def sequence(self, name: str) -> Sequence:
        """The sequence called ``name``."""
        for s in self.sequences:
            if s.name == name:
                return s
        raise KeyError(f"dataset {self.name} has no sequence {name!r}")

    @property
    def skeleton(self) -> Skeleton:
        if not self.sequences:
            raise ValueError(f"dataset {self.name} has no sequences")
        return self.sequences[0].skeleton


def load_dataset(path: PathLike) -> Dataset:
    """Reads a dataset directory, or any source ``socdiff data convert`` reads (a .bvh file or
    folder, a Haggling .pkl, a Panoptic folder), with the CLI's default import options."""
    raw = _native.load_dataset(_path(path))
    sequences = [
        Sequence(
            name=s["name"],
            split=s["split"],
            fps=s["fps"],
            skeleton=Skeleton._from_native(s["skeleton"]),
            positions=s["positions"],
            valid=s["valid"],
            signals=dict(s["signals"]),
            persons=list(s["persons"]),
            metadata=json.loads(s["metadata"]),
        )
        for s in raw["sequences"]
    ]
    return Dataset(name=raw["name"], sequences=sequences, metadata=json.loads(raw["metadata"]))


def save_dataset(path: PathLike, dataset: Dataset) -> None:
    """Writes ``dataset`` as a dataset directory at ``path`` (which must not exist or be empty):
    written whole or not at all; ``socdiff`` commands and :func:`load_dataset` read it."""
    sequences = []
    for s in dataset.sequences:
        positions = _positions(s.positions, f"sequence {s.name!r} positions")
        persons = s.persons or [(str(p), None) for p in range(positions.shape[1] if positions.ndim == 4 else 0)]
        sequences.append(
            {
                "name": s.name,
                "split": s.split,
                "fps": float(s.fps),
                "skeleton": s.skeleton._native(),
                "positions": positions,
                "valid": None if s.valid is None else np.ascontiguousarray(s.valid, dtype=np.bool_),
                "signals": {k: _positions(v, f"signal {k!r}") for k, v in s.signals.items()},
                "persons": persons,
                "metadata": json.dumps(s.metadata),
            }
        )
    _native.save_dataset(_path(path), dataset.name, json.dumps(dataset.metadata), sequences)


class Forecast(NamedTuple):
    """Samples and how they were made."""

    samples: FloatArray
    """``[K, frames, persons, joints, 3]`` in the model's skeleton and frame rate; for a
    forecast, frames ``0..observe`` are the observed ones and ``observe..`` the future."""
    provenance: Dict[str, Any]
    """Model, sampler, steps, seeds, timings (as the CLI writes in dataset.json)."""


class Model:
    """A trained model: a run directory, its checkpoint, or a model.safetensors file."""

    def __init__(self, native: _native.Model) -> None:
        self._native = native

    @staticmethod
    def load(path: PathLike, weights: str = "ema") -> "Model":
        """Loads ``path``; ``weights`` "ema" (the moving average, for inference) or "online"."""
        return Model(_native.Model.load(_path(path), weights))

    @property
    def skeleton(self) -> Skeleton:
        return Skeleton._from_native(self._native.skeleton)

    @property
    def fps(self) -> float:
        return self._native.fps

    @property
    def step(self) -> int:
        return self._native.step

    @property
    def path(self) -> str:
        return self._native.path

    @property
    def config(self) -> Dict[str, Any]:
        """The training configuration (a run's config.json)."""
        result: Dict[str, Any] = json.loads(self._native.config_json)
        return result

    def _layout(self, skeleton: Union[Skeleton, str, None], joints: Optional[Seq[str]]) -> Optional[Skeleton]:
        if skeleton is not None and joints is not None:
            raise ValueError("give `skeleton` or `joints`, not both")
        if isinstance(skeleton, str):
            return Skeleton.named(skeleton)
        if joints is not None:
            return Skeleton.from_joint_names(joints)
        return skeleton

    def forecast(
        self,
        positions: npt.ArrayLike,
        *,
        observe: int = 30,
        horizon: int = 90,
        samples: int = 1,
        seed: int = 0,
        steps: Optional[int] = None,
        fps: Optional[float] = None,
        skeleton: Union[Skeleton, str, None] = None,
        joints: Optional[Seq[str]] = None,
        sampler: str = "ddim",
        eta: float = 0.0,
        conditioning: str = "replace",
        clean_known: str = "auto",
        joint_map: Optional[bool] = None,
        name: str = "scene",
    ) -> Forecast:
        """Samples ``samples`` futures of ``horizon`` frames after the first ``observe`` frames
        of ``positions`` ``[frames, persons, joints, 3]``.

        ``fps`` and ``skeleton`` (a :class:`Skeleton` or a name) or ``joints`` (joint names)
        describe ``positions`` when they are not the model's: the scene is resampled to the
        model's frame rate, and its joints are mapped onto the model's by name (``joint_map``,
        on when a skeleton or joints are given). ``steps`` DDIM steps (default 50, or a distilled
        student's own calls; ``sampler`` "ddpm": all of the model's), ``eta`` DDIM stochasticity. Sample k's seed derives from (seed, k), as
        in the CLI, whose ``forecast`` this equals bit for bit.
        """
        layout = self._layout(skeleton, joints)
        mapped = layout is not None if joint_map is None else joint_map
        data, provenance = self._native.forecast(
            _positions(positions),
            None if layout is None else layout._native(),
            fps,
            name,
            observe,
            horizon,
            samples,
            seed,
            sampler,
            steps,
            eta,
            conditioning,
            clean_known,
            mapped,
        )
        return Forecast(data, json.loads(provenance))

    def complete(
        self,
        positions: npt.ArrayLike,
        missing: str,
        *,
        samples: int = 1,
        seed: int = 0,
        steps: Optional[int] = None,
        fps: Optional[float] = None,
        skeleton: Union[Skeleton, str, None] = None,
        joints: Optional[Seq[str]] = None,
        sampler: str = "ddim",
        eta: float = 0.0,
        conditioning: str = "replace",
        clean_known: str = "auto",
        joint_map: Optional[bool] = None,
        name: str = "scene",
    ) -> Forecast:
        """Fills in what ``missing`` names — ``"joints=left_wrist,right_wrist"``,
        ``"frames=30..60"`` or ``"persons=1"`` — keeping the rest of ``positions``."""
        layout = self._layout(skeleton, joints)
        mapped = layout is not None if joint_map is None else joint_map
        data, provenance = self._native.complete(
            _positions(positions),
            missing,
            None if layout is None else layout._native(),
            fps,
            name,
            samples,
            seed,
            sampler,
            steps,
            eta,
            conditioning,
            clean_known,
            mapped,
        )
        return Forecast(data, json.loads(provenance))

    def generate(
        self,
        frames: int,
        *,
        persons: int = 3,
        layout: Optional[npt.ArrayLike] = None,
        skeleton: Union[Skeleton, str, None] = None,
        fps: Optional[float] = None,
        samples: int = 1,
        seed: int = 0,
        steps: Optional[int] = None,
        sampler: str = "ddim",
        eta: float = 0.0,
    ) -> Forecast:
        """Generates ``frames`` frames of motion from noise: ``persons`` persons on a circle, or
        the persons of ``layout`` (positions whose first frame places them)."""
        shape = self._layout(skeleton, None)
        data, provenance = self._native.generate(
            frames,
            persons,
            None if layout is None else _positions(layout, "layout"),
            None if shape is None else shape._native(),
            fps,
            samples,
            seed,
            sampler,
            steps,
            eta,
        )
        return Forecast(data, json.loads(provenance))

    def stream(
        self,
        persons: int,
        *,
        observe: int = 30,
        horizon: int = 90,
        samples: int = 1,
        seed: int = 0,
        steps: Optional[int] = None,
        sampler: str = "ddim",
        eta: float = 0.0,
    ) -> "Stream":
        """A stream of ``persons`` persons in the model's skeleton and frame rate: push one
        frame at a time, get a forecast per frame once ``observe`` frames are in (the seed of
        the forecast at the n-th frame is ``seed + n``). At 30 Hz, ``steps=2`` keeps a forecast
        of 3 persons, K = 8, within a frame period on 2 cores (docs/results.md#real-time)."""
        return Stream(self._native.stream(persons, observe, horizon, samples, seed, sampler, steps, eta))

    def __repr__(self) -> str:
        s = self.skeleton
        return f"socdiff.Model({self.path!r}, step {self.step}, {s.name} ({s.num_joints} joints), {self.fps:g} fps)"


class Stream:
    """Frames in, a forecast per frame out (:meth:`Model.stream`). A frame of the wrong shape,
    a non-finite value or a time that goes backwards raises ValueError and changes nothing; a
    gap in time (a frame more than half a period late) restarts the window."""

    def __init__(self, native: _native.Stream) -> None:
        self._native = native

    def push(self, time: float, frame: npt.ArrayLike) -> Optional[Forecast]:
        """Takes the frame ``[persons, joints, 3]`` (metres, z up) observed at ``time``
        seconds; returns the forecast from the last ``observe`` frames once that many are in:
        samples ``[K, observe + horizon, persons, joints, 3]``."""
        f = _positions(frame, "frame")
        if f.ndim != 3 or f.shape[-1] != 3:
            raise ValueError(f"frame: shape {list(f.shape)}, expected [persons, joints, 3]")
        out = self._native.push(float(time), f)
        return None if out is None else Forecast(out[0], json.loads(out[1]))

    @property
    def frames_needed(self) -> int:
        """Frames the window still lacks before the first forecast."""
        return self._native.frames_needed


def _flags(options: Mapping[str, Any]) -> List[str]:
    """Keywords as the CLI's flags: ``save_every=500`` → ``--save-every 500``; True → the bare
    flag; None and False → left out; a list → comma-separated."""
    args: List[str] = []
    for key, value in options.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            args.append(flag)
        elif isinstance(value, (list, tuple)):
            args += [flag, ",".join(str(v) for v in value)]
        elif isinstance(value, (os.PathLike, str, int, float)):
            args += [flag, os.fspath(value) if isinstance(value, os.PathLike) else str(value)]
        else:
            raise TypeError(f"option `{key}`: {type(value).__name__} is not a number, string, path or list")
    return args


def _progress_bar() -> Callable[[TrainEvent], None]:
    """A one-line progress display on stderr (the default when stderr is a terminal)."""
    state: Dict[str, Any] = {"total": 0, "minutes": None}

    def show(event: TrainEvent) -> None:
        kind = event["kind"]
        if kind == "started":
            state["total"], state["minutes"] = event["total_steps"], event["minutes"]
        elif kind == "step":
            if state["minutes"]:
                left = max(0.0, state["minutes"] * 60 - event["seconds"])
                where = f"{left / 60:5.1f} min left"
            else:
                where = f"of {state['total']}"
            sys.stderr.write(f"\rstep {event['step']} {where}  loss {event['loss']:.4f}   ")
            sys.stderr.flush()
        elif kind in ("saved", "notice", "validation"):
            text = {"saved": "saved {path}", "notice": "note: {message}", "validation": "validation loss {loss:.5f}"}[kind]
            sys.stderr.write("\r" + text.format(**event) + "\n")

    return show


def train(
    data: Union[PathLike, Seq[PathLike]],
    out: PathLike,
    *,
    minutes: Optional[float] = None,
    steps: Optional[int] = None,
    preset: str = "recommended",
    config: Optional[PathLike] = None,
    resume: bool = False,
    init: Optional[PathLike] = None,
    force: bool = False,
    device: str = "cpu",
    progress: Optional[Callable[[TrainEvent], None]] = None,
    **fields: Any,
) -> Dict[str, Any]:
    """Trains a model in the run directory ``out``, as ``socdiff train`` does with the same
    options: ``data`` one source or several, ``minutes`` of wall-clock time and/or ``steps``,
    ``preset`` "recommended" or "paper", a JSON ``config`` file, and ``fields`` named as the
    CLI's options (``hidden=32``, ``batch=8``, ``lr=1e-3``, ``seed=1``, ``window=120``,
    ``save_every=500``, ``val_every=0``).

    ``progress`` hears every event (default: a progress line when stderr is a terminal). Ctrl-C
    (KeyboardInterrupt), or an exception raised by ``progress``, stops training after the
    current step, saves a checkpoint that ``resume=True`` continues, and is raised. Returns the
    summary: first and last step, every loss, validation losses, the checkpoint's path.
    """
    sources = [data] if isinstance(data, (str, os.PathLike)) else list(data)
    if progress is None and sys.stderr.isatty():
        progress = _progress_bar()
    overrides = _flags({"steps": steps, "minutes": minutes, **fields})
    summary: Dict[str, Any] = _native.train(
        [_path(s) for s in sources],
        _path(out),
        preset,
        None if config is None else _path(config),
        resume,
        None if init is None else _path(init),
        force,
        overrides,
        device,
        progress,
    )
    summary["config"] = json.loads(summary["config"])
    return summary


def evaluate(
    reference: PathLike,
    *,
    forecasts: Union[PathLike, Seq[PathLike], Mapping[str, PathLike], None] = None,
    baselines: Union[str, Seq[str], None] = None,
    split: str = "test",
    out: Optional[PathLike] = None,
    **options: Any,
) -> Dict[str, Any]:
    """Scores forecasts against a reference dataset, as ``socdiff eval`` does, and returns the
    report (report.json's content). ``forecasts``: forecast directories (one, a list, or
    ``{label: dir}``); ``baselines``: "all" or names (zero-velocity, constant-velocity,
    nearest, ground-truth); ``out``: also write report.json and the plots there. Other options
    are named as the CLI's (``observe=30``, ``horizon=90``, ``metrics="mpjpe,ndms"``,
    ``horizons=[1, 2, 3]``, ``generated=...``)."""
    if isinstance(forecasts, Mapping):
        specs = [f"{label}={_path(d)}" for label, d in forecasts.items()]
    elif forecasts is None:
        specs = []
    elif isinstance(forecasts, (str, os.PathLike)):
        specs = [_path(forecasts)]
    else:
        specs = [_path(d) for d in forecasts]
    args = _flags({"reference": _path(reference), "split": split, **options})
    for spec in specs:
        args += ["--forecasts", spec]
    if baselines is not None:
        args += ["--baselines", baselines if isinstance(baselines, str) else ",".join(baselines)]
    # `out` is required by the CLI's options; without it nothing is written.
    args += ["--out", _path(out) if out is not None else "-"]
    report: Dict[str, Any] = json.loads(_native.evaluate(args, out is not None))
    return report
