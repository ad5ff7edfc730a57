"""Named noise models: how a real robot's motion and pose sensor differ from a perfect one.

``kgnav eval --noise SPEC`` (and :class:`~kgnav.envs.EnvOptions` ``noise``) takes

* ``none`` — no noise (an environment's default, :data:`DEFAULT_NOISE`, as in the ObjectNav
  task);
* ``locobot`` — a low-cost wheeled base (:func:`locobot`; the benchmark's default,
  :data:`BENCHMARK_NOISE`), with optional modifiers
  ``scale=K`` (every noise standard deviation and mean multiplied by K), ``slip=F`` (the mean
  share of a bumped move's blocked length the wheel odometry reports as motion; default 0.5)
  and ``depth=S``;
* ``actuation=K,odometry=S`` — the older generic levels (:meth:`NoiseModel.scaled` and S m /
  S° of pose-sensor noise per step);

and any of them with ``depth=S``: Gaussian depth noise of S m per metre of depth (kgnav's
simulator and MiniWorld). :func:`parse_noise` turns a spec into a :class:`NoiseSpec`, or a
one-line :class:`~kgnav.errors.KgnavError`.

>>> spec = parse_noise("locobot,depth=0.01")
>>> spec.name, spec.depth, spec.actuation.active, spec.odometry.active
('locobot', 0.01, True, True)
>>> parse_noise("none") == parse_noise(None) == NoiseSpec()
True
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

from kgnav.errors import KgnavError
from kgnav.sim.dynamics import NoiseModel, OdometryModel

#: The noise an environment has when nobody asks for any: none, a simulator is exact.
DEFAULT_NOISE = "none"
#: The noise a benchmark run (``kgnav eval``, :class:`~kgnav.benchmark.EvalConfig`) has unless
#: told otherwise: a real robot's, because memory is where drift hurts and no robot has a perfect
#: pose sensor. ``--noise none`` (or ``--preset paper``) gives the noise-free task.
BENCHMARK_NOISE = "locobot"


@dataclass(frozen=True)
class NoiseSpec:
    """A resolved noise setting: its ``name`` (``none``, ``locobot``, or ``custom`` for the
    ``actuation=K,odometry=S`` levels), the motion noise, the pose sensor, and depth noise
    (``depth``: standard deviation in m per metre of depth; 0: noiseless). ``text``: the spec
    it was parsed from, canonical (config.json records it with :meth:`to_dict`)."""

    name: str = "none"
    actuation: NoiseModel = field(default_factory=NoiseModel)
    odometry: OdometryModel = field(default_factory=OdometryModel)
    depth: float = 0.0
    text: str = "none"

    @property
    def active(self) -> bool:
        return self.actuation.active or self.odometry.active or self.depth > 0

    def to_dict(self) -> dict:
        """Name and every parameter (SI units, radians), for config.json."""
        return {"name": self.name, "spec": self.text, "actuation": asdict(self.actuation),
                "odometry": asdict(self.odometry), "depth_per_m": self.depth}


def locobot(scale: float = 1.0, slip: float = 0.0) -> tuple[NoiseModel, OdometryModel]:
    """A LoCoBot's motion and wheel odometry, every standard deviation and mean times
    ``scale`` (``slip``: the mean share of a bump's blocked length reported as motion), for
    kgnav's actions (0.25 m forward, 30° turns; the same as the Habitat
    Challenge 2020 PointNav task these numbers were used in).

    **Motion** (where the base really goes): habitat-sim's PyRobot noise model of the LoCoBot
    with its ``Proportional`` controller at ``noise_multiplier=0.5``, the Habitat Challenge
    2020 PointNav setting (habitat-sim ``habitat_sim/agent/controls/pyrobot_noisy_controls.py``,
    fitted on a real LoCoBot: Murali et al. 2019, "PyRobot"; Kadian et al. 2020, "Sim2Real
    predictivity"). habitat-sim lists, per motion, means and *variances* of diagonal Gaussians
    truncated at ±3 σ; times 0.5:

    * a forward move: along +8.5 mm (σ 41.8 mm), sideways 21 mm to the right (σ 75.8 mm), a
      heading change of +0.89° to the left (σ 4.6°);
    * a turn: an overshoot of 1.23° in the turn's direction (σ 3.7°) and a shift of 0.5 mm
      forward (σ 15.8 mm) and 2.5 mm to the right (σ 31.6 mm).

    A move that bumps into something twists the base further (kgnav's assumption, not in the
    reference): an extra heading error as large as a free move's (σ 4.6°).

    **Pose sensor** (wheel odometry, what the agent is told): the true motion plus an error
    whose standard deviation grows with the distance moved and the angle turned (a random
    walk: drift grows with the distance travelled). The rates come from the LoCoBot odometry
    ("sensor") noise of Active Neural SLAM (Chaplot et al. 2020, ICLR; ``noise_models/
    sensor_noise_*.pkl`` of github.com/devendrachaplot/Neural-SLAM, 2-component Gaussian
    mixtures per action, here moment-matched to one Gaussian, means dropped: a calibrated
    odometry): per forward move of 0.25 m σ 2.73 mm along and 2.31 mm sideways (1.09 and 0.92
    cm per metre), heading 0.002° (negligible); per 10° turn σ 0.084° of heading and 1.5 mm
    of position (0.48° and 8.6 mm per radian turned). Wheel slip (``slip``; kgnav's assumption,
    not in the references, so off by default: a LoCoBot's base stops on its bumper): a move
    stopped by an obstacle has its wheels turn on, so the odometry reports a share of the
    blocked distance as forward motion that never happened — on average ``slip`` of it (σ half
    of that, clipped to [0, 1]); ``slip=0.5`` is a base without a bumper."""
    k = float(scale)
    act = NoiseModel(
        forward_sigma=k * 0.5 * math.sqrt(0.007), lateral_sigma=k * 0.5 * math.sqrt(0.023),
        forward_turn_sigma=k * 0.5 * math.sqrt(0.026), turn_sigma=k * 0.5 * math.sqrt(0.017),
        forward_mean=k * 0.5 * 0.017, lateral_mean=-k * 0.5 * 0.042,
        forward_turn_mean=k * 0.5 * 0.031, turn_mean=k * 0.5 * 0.043,
        turn_forward_sigma=k * 0.5 * math.sqrt(0.001),
        turn_lateral_sigma=k * 0.5 * math.sqrt(0.004),
        turn_forward_mean=k * 0.5 * 0.001, turn_lateral_mean=-k * 0.5 * 0.005,
        bump_turn_sigma=k * 0.5 * math.sqrt(0.026), clip=3.0)
    odo = OdometryModel(
        forward_per_m=k * 0.00273 / 0.25, lateral_per_m=k * 0.00231 / 0.25,
        theta_per_m=k * math.radians(0.00224) / 0.25,
        theta_per_rad=k * math.radians(0.0835) / math.radians(10.0),
        xy_per_rad=k * 0.0015 / math.radians(10.0),
        slip=float(slip) if k > 0 else 0.0, slip_sigma=0.5 * float(slip) if k > 0 else 0.0)
    return act, odo


#: Named noise models: name -> factory(scale[, slip]) -> (motion noise, pose sensor).
NOISE_MODELS: dict[str, Callable[[float], tuple[NoiseModel, OdometryModel]]] = {
    "none": lambda scale=1.0, slip=0.0: (NoiseModel(), OdometryModel()),
    "locobot": locobot,
}
_NAMED_KEYS = ("scale", "slip", "depth")
_FORMS = (f"{'|'.join(NOISE_MODELS)}[,scale=K][,slip=F][,depth=S] or "
          f"actuation=K[,odometry=S][,depth=S]")
_LEVEL_KEYS = ("actuation", "odometry", "depth")


def levels(actuation: float = 0.0, odometry: float = 0.0) -> tuple[NoiseModel, OdometryModel]:
    """The generic levels: :meth:`NoiseModel.scaled` (``actuation``) and ``odometry`` m and
    ``odometry`` degrees of pose-sensor noise per step."""
    return (NoiseModel.scaled(float(actuation)),
            OdometryModel(sigma_xy=float(odometry), sigma_theta=math.radians(float(odometry))))


def parse_noise(text: str | None) -> NoiseSpec:
    """``NAME[,scale=K][,depth=S]`` or ``actuation=K[,odometry=S][,depth=S]`` (see the module
    doc) -> :class:`NoiseSpec`; a one-line :class:`KgnavError` for an unknown name or key, a
    repeated key, or a value that is not a number >= 0."""
    text = (text or DEFAULT_NOISE).strip()
    parts = [p.strip() for p in text.split(",")]
    name = None
    if parts and "=" not in parts[0]:
        name = parts.pop(0)
        if name not in NOISE_MODELS:
            raise KgnavError(f"unknown noise model {name!r} (expected {_FORMS})")
    allowed = _NAMED_KEYS if name is not None else _LEVEL_KEYS
    values: dict[str, float] = {}
    for part in parts:
        key, eq, v = (s.strip() for s in part.partition("="))
        if not eq:
            raise KgnavError(f"noise {text!r}: expected KEY=VALUE, got {part!r}")
        if key not in allowed:
            raise KgnavError(f"noise {text!r}: unknown setting {key!r} (expected {_FORMS})")
        if key in values:
            raise KgnavError(f"noise {text!r}: {key} given twice")
        try:
            x = float(v)
        except ValueError:
            raise KgnavError(f"noise {text!r}: {key} needs a number, got {v!r}") from None
        if not (x >= 0 and math.isfinite(x)):
            raise KgnavError(f"noise {text!r}: {key} must be a number >= 0, got {v!r}")
        values[key] = x
    depth = values.pop("depth", 0.0)
    if name is not None:
        if values.get("slip", 0.0) > 1:
            raise KgnavError(f"noise {text!r}: slip is a share, from 0 to 1")
        act, odo = NOISE_MODELS[name](values.get("scale", 1.0),
                                      **({"slip": values["slip"]} if "slip" in values else {}))
    else:
        act, odo = levels(values.get("actuation", 0.0), values.get("odometry", 0.0))
        name = "custom" if act.active or odo.active else "none"
    canon = ",".join([*([name] if name != "custom" else []),
                      *(f"{k}={values[k]:g}" for k in sorted(values)),
                      *([f"depth={depth:g}"] if depth else [])])
    return NoiseSpec(name, act, odo, depth, canon or "none")


def resolve_noise(noise: str | NoiseSpec | None = None, actuation: float = 0.0,
                  odometry: float = 0.0) -> NoiseSpec:
    """The noise of a run given by spec (``noise``) and/or by the older float levels
    (``actuation``, ``odometry``: :class:`~kgnav.envs.EnvOptions`' and the simulator's
    arguments). A named model and levels together is an error."""
    spec = noise if isinstance(noise, NoiseSpec) else parse_noise(noise)
    if actuation < 0 or odometry < 0:
        raise KgnavError("noise levels must be >= 0")
    if not (actuation or odometry):
        return spec
    if spec.actuation.active or spec.odometry.active:
        raise KgnavError(f"noise {spec.text!r} and actuation/odometry levels: give one or "
                         f"the other")
    act, odo = levels(actuation, odometry)
    text = ",".join(p for p in (f"actuation={actuation:g}" if actuation else "",
                                f"odometry={odometry:g}" if odometry else "",
                                f"depth={spec.depth:g}" if spec.depth else "") if p)
    return replace(spec, name="custom", actuation=act, odometry=odo, text=text)
