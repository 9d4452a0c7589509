"""The force models, one interface: fitted from a sweep, predict the force for a current, invert.

- ``nonhysteretic``: the paper's Eq. 1, F = law(i), with the static law identified from the sweep
  (:mod:`.calibration`: a bench never equals its preset's MEC, so the preset's geometry is not used);
- ``paper``: Eq. 6, the same law with the current delayed by theta_hyst(f) measured per frequency
  (flux behind current, the paper's Sec. VII), interpolated in frequency;
- ``best``: the description the sweep's held-out recordings choose (:mod:`.choice`) among all of them:
  the two above, a Preisach iron plus eddy term (:class:`~.hysteresis_eddy.HysteresisEddyModel`), a
  describing function (:class:`~.describing.DescribingFunctionModel`) or Rayleigh loops
  (:class:`~.rayleigh_loop.RayleighLoopModel`); never worse than a simpler one where the data can tell.

Every model works on one period (``force_period``: current -> the actuator's force;
``current_period``: force -> current, which is the feed-forward).  What the load cell reports is
the model's force through the instrument's response (:func:`predict_measured`): the instrument is
corrected in the measurement, never put into the actuator's command.

A :class:`ModelSet` is what ``hystbench model fit`` writes: the rig, the instrument model used,
the three models, what the identification found (law, magnet bias and flux map with standard
errors), the best model's choice (which description, why, every description's held-out accuracy) and how well each model fits the sweep (JSON, ``FORMAT``; files of
the first format, ``hystbench-force-models/1``, are still read: their models are the same kinds).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import ConfigError
from ..physics import presets
from ..physics.instrument import InstrumentModel
from .calibration import calibrate, fit_delayed_law
from .choice import choose_best
from .data import PeriodData
from .describing import DescribingFunctionModel
from .errors import CompensatorError
from .force_model import ForceModel, NonHysteretic, PaperModel, force_error, paper_model, predict_measured
from .hysteresis_eddy import HysteresisEddyModel, IronScaling
from .periodic import apply_response, shift
from .rayleigh_loop import RayleighLoopModel
from .static import StaticLaw

__all__ = ["ForceModel", "NonHysteretic", "PaperModel", "ModelSet", "MODEL_KINDS", "FORMAT", "fit_models", "paper_model",
           "predict_measured", "force_error", "model_from_dict", "phase_delay_bound_n"]

FORMAT = "hystbench-force-models/2"
#: Earlier formats this version reads (their entries are a subset of this one's).
READABLE_FORMATS = (FORMAT, "hystbench-force-models/1")
#: The largest model file read (16 MiB): a fitted model set is a few kB of JSON.
MAX_MODEL_BYTES = 16 << 20
MODEL_KINDS = ("nonhysteretic", "paper", "best")
#: The best model's iron descriptions, by the ``name`` a model file gives them (format 1: always Preisach).
BEST_DESCRIPTIONS = {cls.name: cls for cls in (HysteresisEddyModel, DescribingFunctionModel, RayleighLoopModel)}
#: The paper's models' names, which a best model may be too (where the sweep chooses them).
PAPER_NAMES = ("eq1_mec", "eq6_phase_delay")


def model_from_dict(d: Mapping[str, Any]) -> ForceModel:
    """The model that a model file's entry describes, by its ``kind`` (the inverse of ``to_dict``)."""
    kind = d.get("kind")
    paper_kind = {"eq1_mec": "nonhysteretic", "eq6_phase_delay": "paper"}.get(d.get("name")) if kind == "best" else kind
    if paper_kind == "nonhysteretic":
        return NonHysteretic(StaticLaw.from_dict(d["law"]), kind=str(kind))
    if paper_kind == "paper":
        f, theta = tuple(map(float, d["frequency_Hz"])), tuple(map(float, d["theta_hyst_rad"]))
        if not f or len(f) != len(theta) or min(f) <= 0:  # else a traceback when it first predicted
            raise ValueError(f"frequency_Hz and theta_hyst_rad must be lists of one length (>= 1), the frequencies > 0; "
                             f"got {len(f)} and {len(theta)}")
        return PaperModel(StaticLaw.from_dict(d["law"]), f, theta, kind=str(kind))
    if kind == "best":
        name = d.get("name", HysteresisEddyModel.name)
        if name not in BEST_DESCRIPTIONS:
            raise ConfigError(f"unknown best-model description {name!r}; known: "
                              f"{', '.join([*PAPER_NAMES, *BEST_DESCRIPTIONS])}")
        return BEST_DESCRIPTIONS[name].from_dict(dict(d))
    raise ConfigError(f"unknown force model kind {kind!r}; known: {', '.join(MODEL_KINDS)}")


# --- a set of models for one rig -----------------------------------------------------------------
@dataclass
class ModelSet:
    """What ``hystbench model fit`` writes and ``compensate`` reads (see the module docstring)."""

    rig: str
    instrument: InstrumentModel
    models: dict[str, ForceModel]
    report: dict = field(default_factory=dict)

    def __getitem__(self, kind: str) -> ForceModel:
        if kind not in self.models:
            raise ConfigError(f"no {kind!r} model in this set; it has {', '.join(self.models)}")
        return self.models[kind]

    def to_dict(self) -> dict:
        ins = self.instrument
        return {"format": FORMAT, "rig": self.rig,
                "instrument": {"fn_Hz": ins.fn_hz, "zeta_n": ins.zeta_n, "f0_Hz": ins.f0_hz, "zeta_0": ins.zeta_0},
                "models": {k: m.to_dict() for k, m in self.models.items()}, "report": self.report}

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        path = Path(path)
        if path.exists() and not overwrite:
            raise ConfigError(f"{path}: exists; give --overwrite to replace it")
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1, default=_json_default) + "\n")
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "ModelSet":
        path = Path(path)
        try:
            with open(path, "rb") as fh:
                raw = fh.read(MAX_MODEL_BYTES + 1)  # bounded: whatever file is given, it is read whole
        except OSError as err:
            raise ConfigError(f"{path}: cannot read the model file: {err}") from err
        if len(raw) > MAX_MODEL_BYTES:
            raise ConfigError(f"{path}: larger than {MAX_MODEL_BYTES} bytes, not a model file (MAX_MODEL_BYTES)")
        try:
            d = json.loads(raw.decode("utf-8"))
        except json.JSONDecodeError as err:
            raise ConfigError(f"{path}: not JSON: {err}") from err
        except UnicodeDecodeError as err:  # a binary file given as the model
            raise ConfigError(f"{path}: not a model file (not UTF-8 text: {err.reason} at byte {err.start})") from err
        except (RecursionError, ValueError) as err:  # nesting past the parser's stack; an int of 5000 digits
            raise ConfigError(f"{path}: not a model file ({type(err).__name__}: {str(err)[:200]})") from err
        if not isinstance(d, dict) or not str(d.get("format", "")).startswith("hystbench-force-models/"):
            raise ConfigError(f"{path}: not a hystbench model file (format {FORMAT!r} expected)")
        if d["format"] not in READABLE_FORMATS:
            raise ConfigError(f"{path}: model file format {d['format']!r} is newer than this hystbench reads "
                              f"({', '.join(READABLE_FORMATS)}); fit the models again with `hystbench model fit`")
        bad = _non_finite(d)
        if bad is not None:  # json reads NaN and Infinity; a model of them predicts NaN without a word
            raise ConfigError(f"{path}: key {bad}: not a finite number")
        try:
            ins = {k: float(d["instrument"][k]) for k in ("fn_Hz", "zeta_n", "f0_Hz", "zeta_0")}
            entries = d["models"].items()
        except (KeyError, TypeError, ValueError, AttributeError) as err:  # a list for a dict
            raise ConfigError(f"{path}: malformed model file: {err!r}") from err
        models = {}
        for k, m in entries:
            try:
                models[k] = model_from_dict(m)
            except (KeyError, TypeError, ValueError, AttributeError, CompensatorError) as err:
                what = f"no key {err}" if isinstance(err, KeyError) else str(err)
                raise ConfigError(f"{path}: key models.{k}: {what}") from err
        if not models:
            raise ConfigError(f"{path}: key models: no model in the file")
        for key, v in ins.items():  # a resonance at -1 Hz predicts nonsense, not an error
            if not v > 0:
                raise ConfigError(f"{path}: key instrument.{key}: must be > 0, got {v!r}")
        instrument = InstrumentModel(*ins.values())
        return cls(str(d["rig"]), instrument, models, dict(d.get("report", {})))


def _non_finite(obj: Any, where: str = "") -> str | None:
    """The dotted key of the first NaN or infinite number in a loaded JSON document, or None."""
    if isinstance(obj, float):
        return None if math.isfinite(obj) else (where or "(the document)")
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        found = _non_finite(v, f"{where}.{k}" if where else str(k))
        if found is not None:
            return found
    return None


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def fit_models(points: Sequence[PeriodData], preset: Mapping[str, Any],
               instrument: InstrumentModel | None = None, *, kinds: Sequence[str] = MODEL_KINDS,
               tick: Callable[[], None] | None = None) -> ModelSet:
    """Every model of ``kinds`` from one bench's sweep (``points``: its recordings as period
    averages).  The force instrument is ``instrument`` (a voice coil's identification), else the
    preset's; the preset's geometry only sets the Preisach description's B scale; the law, the
    magnet's bias and the iron come from the sweep."""
    rig = str(preset.get("name"))
    if preset.get("actuator") != "ecore":
        raise CompensatorError(f"rig {rig!r} is a {preset.get('actuator')}, not an E-core: the force models are "
                               "the E-core's")
    if not points:
        raise CompensatorError(f"{rig}: no recordings to fit the force models on")
    instrument = instrument or presets.instrument(preset)
    magnet = "magnet" in preset
    th = [(p.nominal_frequency_hz, p.theta_hyst_rad) for p in points if np.isfinite(p.theta_hyst_rad)]
    if "paper" in kinds and not th:
        raise CompensatorError(f"{rig}: no theta_hyst measured in the sweep; the paper's Eq. 6 needs it")
    identification: dict[str, Any] = {}
    models: dict[str, ForceModel] = {}
    if "nonhysteretic" in kinds or "paper" in kinds:
        law, law_se = fit_delayed_law(points, instrument, magnet)
        identification["eq6_law"] = {**law.to_dict(), "se": dict(zip(("k0_N", "k1_N_per_A", "k2_N_per_A2"), law_se))}
        if "nonhysteretic" in kinds:
            models["nonhysteretic"] = NonHysteretic(law)
        if "paper" in kinds:
            models["paper"] = paper_model(points, law)
    choice = None
    if "best" in kinds:
        cal = calibrate(points, instrument, magnet)
        identification.update(cal.report)
        models["best"], choice = choose_best(points, cal, IronScaling.from_mec(presets.ecore_mec(preset)),
                                             instrument, magnet, tick=tick)
    fit = {k: [_summary(force_error(m, p, instrument)) for p in points] for k, m in models.items()}
    report = {"recordings": [p.name for p in points], "identification": identification, "training_error": fit}
    if choice is not None:
        report["choice"] = choice
    return ModelSet(rig, instrument, models, report)


def phase_delay_bound_n(point: PeriodData, instrument: InstrumentModel, *, max_theta_deg: float = 4.0,
                        steps: int = 161) -> float:
    """The smallest max|dF| any model of Eq. 6's form can reach on ``point`` itself: the current
    delayed by theta (grid search), then k0 + k1 i + k2 i^2 fitted by least squares to the very
    recording, through the instrument.  A bound, not a model: it sees the answer."""
    best = np.inf
    for theta_deg in np.linspace(0.0, max_theta_deg, steps):
        i = shift(point.current_a, theta_deg / 360.0)
        a = np.stack([apply_response(c, point.frequency_hz, instrument.frequency_response)
                      for c in (np.ones_like(i), i, i * i)], axis=1)
        coef = np.linalg.lstsq(a, point.force_n, rcond=None)[0]
        best = min(best, float(np.max(np.abs(point.force_n - a @ coef))))
    return best


def _summary(e: dict) -> dict:
    return {k: v for k, v in e.items() if not isinstance(v, np.ndarray)}
