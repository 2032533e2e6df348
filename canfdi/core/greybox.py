"""Grey-box templates: physical models of common drives, fitted to a healthy log.

A user with a drive but no model writes ``model: {identify: {template: dc_motor, ...}}`` and
`canfdi identify` learns the model from a healthy log. A template is a nonlinear
continuous-time model whose state has a fixed physical meaning (its output roles, in order:
currents, speed, position, a setpoint echo); its parameters start from a datasheet and are
fitted by prediction error. Because the template fixes the state's meaning, it also knows
where the unmeasured inputs enter (the load torque, friction, the nonlinear terms the linear
monitor cannot carry): the directions F of the unknown inputs, which the parity monitor's
residuals are decoupled from. `fit_template` returns the fitted parameters with their
uncertainty and the discrete linear model (A, B, C, F, dt) the monitor runs on.

The criterion: the one-step prediction error with measured states. For every sample k whose
state x(k) and a row of x(k+1) are measured, the template's ODE is integrated over one period
from the measured x(k) with u(k) held (RK4, all k at once) and compared with the measured
x(k+1). The rows the unknown input reaches are differenced in time, e(k) - e(k-1), so that a
load that is constant or drifts slowly cancels (a step leaves one spike, which the robust
loss and the outlier trim below take care of).

Three things make the estimate honest where a plain least squares would not be:

* Errors in variables. The regressor x(k) is measured, so its noise is in the model's
  argument as well as in the error, and least squares shrinks the fitted dynamics: on seed
  001's motor at the scenario's noise (120 s), by 2 to 10 of the parameters' standard
  deviations. After the least-squares fit, the estimate is refined by instrumental variables:
  sum_k z(k) e(k, theta) = 0, with z(k) the error's sensitivity d e(k) / d theta evaluated
  with the measured state replaced by x_hat(k | k-2), its prediction from the measured
  x(k-2), which carries none of the noise in e(k) (white measurement noise). These equations
  are solved by scipy.optimize.least_squares too.
* Correlated errors. e(k) holds n(k+1) and n(k), a differenced row three samples of noise,
  so the errors are not white and s^2 (J^T J)^-1 misstates the covariance (on Chan et al. 2006's
  motor it overstates some standard deviations 4 to 7 times). The covariance is the
  instrumental-variable sandwich (Z^T J)^-1 (Z^T S Z) (J^T Z)^-1 with Z^T S Z from sums over
  blocks of consecutive samples (batch means), right for any short-range correlation and any
  scale per row.
* Parameters the data do not determine. A direction in which the Jacobian is singular, or a
  parameter whose relative standard deviation exceeds ``max_rel_std``, is reported as not
  determined and held at its start value (the datasheet's), and the others are refitted:
  never returned silently as if it were known.

What is assumed: white measurement noise; an unknown input that varies slowly but for
steps (the differenced rows); commands free of the measurement noise. A loop closed on a noisy
measurement breaks the last a little: u(k) then holds a part of n(k), the instruments use
u(k), and the estimate moves by about sqrt(N) x (that part's size / the sample-to-sample
variation of the command) of its standard deviations. On the servo test (a PI velocity loop
on a velocity measured to 0.01 turns/s) that is -1.7 standard deviations of J at 100 s
without excitation, -0.8 with a +/-0.1 N m dither on the torque command; a commissioning log
with such a dither keeps it small. (Instruments from data before k only avoid it but lose the
dither's information: Chan et al. 2006's L_f is then not determined.)

Parameters are optimised in log space (positive bounds; a relative step means the same for
Ohms and kg m^2), weighted per row by the row's error standard deviation (given as sensor
noise, or estimated robustly from the residuals, re-estimated until it settles).

`TEMPLATES` is the registry and the only place that branches on a template's name:

* ``dc_motor``, Chan et al. 2006's shunt-field motor (eq. 42), x = [i_f, i_a, omega], u = [V]:
  di_f/dt = (V - R_f i_f)/L_f, di_a/dt = (V - R_a i_a - M i_f omega)/L_a,
  domega/dt = (M i_f i_a - D omega - T_L)/J, T_L unknown. For the monitor the bilinear terms
  and the load are the unknown inputs, as in the paper: A = diag(-R_f/L_f, -R_a/L_a, -D/J),
  B = [1/L_f, 1/L_a, 0]^T, F = [e2, e3] (phi1 into i_a, phi2 = the torque over J, load
  included, into omega), discretised with the input.
* ``servo_axis``, a drive in torque control (ODrive-like), x = [Iq_sp, Iq, omega, theta]
  (SI), u = [T] (N m): the drive holds Iq_sp(k+1) = u(k)/Kt exactly (a discrete row, the
  setpoint echo), dIq/dt = (T/Kt - Iq)/tau_i, domega/dt = (Kt Iq - b omega - T_d)/J with T_d
  the load torque and Coulomb friction (unknown, the one unknown input load_torque),
  dtheta/dt = omega. The setting ``unit`` says whether the drive reports velocity and
  position in turns (default) or radians; the monitor's model is in the drive's units.

Examples
--------
>>> import numpy as np
>>> t = get_template("servo_axis")
>>> [p.name for p in t.parameters]
['Kt', 'tau_i', 'J', 'b']
>>> t.outputs, sorted(t.optional)
(('current_setpoint', 'current', 'velocity', 'position'), ['current_setpoint', 'position'])
>>> datasheet = np.array([p.default for p in t.parameters])
>>> A, B, C, F = t.linear_model(datasheet, 0.01, ("current", "velocity"), {"unit": "turn"})
>>> A.shape, F.shape, np.round(A[0, 0], 4)
((2, 2), (2, 1), np.float64(0.2865))
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares as _scipy_least_squares

from canfdi.core._check import check_shape
from canfdi.core.identify import least_squares
from canfdi.core.model import StateSpace, zoh
from canfdi.core.settings import nearest
from canfdi.core.validation import robust_std

__all__ = [
    "TEMPLATES",
    "Parameter",
    "ParameterEstimate",
    "Setting",
    "StaticRow",
    "Template",
    "TemplateFit",
    "fit_template",
    "get_template",
]

#: A parameter whose relative standard deviation exceeds this is "not determined".
MAX_REL_STD = 0.5
#: A Jacobian direction whose singular value is below this fraction of the largest is singular.
SINGULAR_RTOL = 1e-7
#: The fastest rate times the RK4 substep is kept at most this.
MAX_RATE_STEP = 0.25
#: Residuals beyond this many robust standard deviations are left out of the final step.
OUTLIER_SIGMAS = 8.0
#: Samples per block of the batch-means estimate of the scores' covariance.
BLOCK = 64
#: Relative step of the central differences (in log parameters).
FD_STEP = 1e-5
#: Usable samples needed per free parameter.
SAMPLES_PER_PARAMETER = 10

ArrayFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class Parameter:
    """A template's physical parameter, with its datasheet default and positive bounds.

    Examples
    --------
    >>> Parameter("R_a", "ohm", 3.84, 0.05, 100.0, "armature resistance").default
    3.84
    """

    name: str
    unit: str
    default: float
    lower: float
    upper: float
    description: str

    def __post_init__(self) -> None:
        if not 0 < self.lower <= self.default <= self.upper < math.inf:
            raise ValueError(f"parameter {self.name}: need 0 < lower <= default <= upper, got "
                             f"{self.lower}, {self.default}, {self.upper}")


@dataclass(frozen=True)
class Setting:
    """A template's setting that is not fitted (the units a drive reports in, say).

    Examples
    --------
    >>> Setting("unit", "turn", ("turn", "rad"), "velocity and position units").default
    'turn'
    """

    name: str
    default: str
    choices: tuple[str, ...]
    description: str


@dataclass(frozen=True)
class Template:
    """A physical model of a drive: what `fit_template` fits and what the monitor gets.

    Attributes
    ----------
    name, description : how the config names it and what it is.
    inputs : the input roles, in the order of U's columns (p = len(inputs)).
    outputs : the output roles; the state is these in this order (n = len(outputs)), in SI.
    optional : output roles a config may leave out. An optional role's state must not enter
        any other state's derivative (the fit fills it with zeros when it is absent).
    parameters : the fitted parameters, in the order of ``theta``.
    unknown_inputs : names of the monitor model's unknown inputs w (the columns of F).
    ode : ``ode(theta (d,), x (N, n), u (N, p)) -> (N, n)`` the nonlinear continuous model
        dx/dt used for fitting, vectorised over samples (no unknown input: it is what the
        differenced rows cancel).
    disturbed_rows : the state rows the unknown input reaches; their one-step errors are
        differenced.
    linear_model : ``linear_model(theta, dt, present, settings) -> (A, B, C, F)`` the monitor's
        discrete model (zero-order hold) over the present output roles ``present`` (in role
        order), in the units the drive reports; C is the identity on them.
    rate : ``rate(theta) -> float`` the fastest rate of the ODE (1/s), for the RK4 substeps.
    discrete : state rows that are not integrated but set each period (a setpoint echo).
    discrete_step : ``discrete_step(theta, x (N, n), u (N, p)) -> (N, len(discrete))`` their
        value at k+1.
    settings : settings that are not fitted.
    si_scale : ``si_scale(settings) -> (n,)``: an output times this is the state in SI.

    Examples
    --------
    >>> t = TEMPLATES["dc_motor"]
    >>> t.inputs, t.outputs, t.unknown_inputs
    (('voltage',), ('field_current', 'armature_current', 'speed'), ('phi1', 'phi2'))
    >>> datasheet = np.array([p.default for p in t.parameters])
    >>> t.ode(datasheet, np.array([[1.9, 10.0, 100.0]]), np.array([[100.0]])).shape
    (1, 3)
    """

    name: str
    description: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    optional: frozenset[str]
    parameters: tuple[Parameter, ...]
    unknown_inputs: tuple[str, ...]
    ode: ArrayFn
    disturbed_rows: tuple[int, ...]
    linear_model: Callable[[np.ndarray, float, tuple[str, ...], Mapping[str, str]],
                           tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    rate: Callable[[np.ndarray], float]
    discrete: tuple[int, ...] = ()
    discrete_step: ArrayFn | None = None
    settings: tuple[Setting, ...] = ()
    si_scale: Callable[[Mapping[str, str]], np.ndarray] | None = None

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def scale(self, settings: Mapping[str, str]) -> np.ndarray:
        """(n,) output units to SI, for ``settings`` (validated)."""
        if self.si_scale is None:
            return np.ones(len(self.outputs))
        return np.asarray(self.si_scale(settings), dtype=float)


@dataclass(frozen=True)
class ParameterEstimate:
    """One parameter of a fit.

    status : "estimated", "fixed" (held by the caller) or "not determined" (the data do not
    determine it: held at its start value, ``std`` is what it would have been when free).
    std : standard deviation (delta method from the log parameter); low, high : 95 % interval.

    Examples
    --------
    >>> e = ParameterEstimate("J", "kg m^2", 0.05, 0.001, 0.048, 0.052, 0.075, "estimated")
    >>> round(e.rel_std, 3)
    0.02
    """

    name: str
    unit: str
    value: float
    std: float
    low: float
    high: float
    start: float
    status: str
    note: str = ""

    @property
    def rel_std(self) -> float:
        return self.std / abs(self.value) if self.value else math.inf


@dataclass(frozen=True)
class StaticRow:
    """An output that is no role, tied to the state by a static relation y_j = row . x.

    column : its column of Y; row (n,) : its C row (output units); std (n,) : standard
    deviations of the row's entries; residual_std : what the relation leaves, output units.

    Examples
    --------
    >>> StaticRow(2, np.array([1.0, 1.0, 0.0]), np.zeros(3), 0.01).column
    2
    """

    column: int
    row: np.ndarray
    std: np.ndarray
    residual_std: float


@dataclass(frozen=True, eq=False)
class TemplateFit:
    """What `fit_template` found.

    Attributes
    ----------
    template : the template fitted; settings : its settings.
    parameters : one ParameterEstimate per template parameter, in template order.
    log_covariance : (d, d) covariance of the log parameters (zero rows for fixed and held).
    model : the monitor's discrete StateSpace (dt, F); its state is ``states``, its outputs
        Y's columns, its inputs U's columns, its unknown inputs ``unknown_inputs``.
    states : the present output roles, in role order.
    unknown_inputs : names of w.
    static_rows : the C rows fitted for Y's columns that are no role.
    residuals : (N, n) one-step prediction errors x(k) - x_hat(k | k-1), output units, not
        differenced (NaN where there is no prediction or the role is absent).
    row_std : (n,) robust standard deviation of each row's fitted error (differenced where
        the row is), output units.
    cost : 0.5 sum of the squared weighted errors at the estimate; residual_variance : their
        mean square per degree of freedom.
    samples : usable one-step pairs; rejected : weighted errors left out as outliers.
    iterations, evaluations : least-squares iterations and error evaluations, all stages.
    substeps : RK4 substeps per period.

    Examples
    --------
    >>> t = get_template("servo_axis")
    >>> rng = np.random.default_rng(0)
    >>> U = 0.05 * np.sign(rng.standard_normal((400, 1)))
    >>> datasheet = np.array([p.default for p in t.parameters])
    >>> A, B, _, _ = t.linear_model(datasheet, 0.01, t.outputs, {"unit": "turn"})
    >>> X = np.zeros((400, 4))  # the drive's linear physics, exact at the samples
    >>> for k in range(399):
    ...     X[k + 1] = A @ X[k] + B @ U[k]
    >>> Y = X[:, 1:3] + 1e-4 * rng.standard_normal((400, 2))
    >>> fit = fit_template(t, U, Y, {"current": 0, "velocity": 1}, 0.01, fixed=["b"])
    >>> [round(float(fit.theta[k] / datasheet[i]), 2) for i, k in enumerate(("Kt", "tau_i", "J"))]
    [1.0, 1.0, 1.0]
    >>> fit.parameters_table()[3]["status"], fit.model.F.shape
    ('fixed', (2, 1))
    """

    template: Template
    settings: dict[str, str]
    parameters: tuple[ParameterEstimate, ...]
    log_covariance: np.ndarray
    model: StateSpace
    states: tuple[str, ...]
    unknown_inputs: tuple[str, ...]
    static_rows: tuple[StaticRow, ...]
    residuals: np.ndarray
    row_std: np.ndarray
    cost: float
    residual_variance: float
    samples: int
    rejected: int
    iterations: int
    evaluations: int
    substeps: int

    @property
    def theta(self) -> dict[str, float]:
        """Parameter name -> value."""
        return {p.name: p.value for p in self.parameters}

    @property
    def undetermined(self) -> tuple[str, ...]:
        """Names of the parameters the data do not determine."""
        return tuple(p.name for p in self.parameters if p.status == "not determined")

    def parameters_table(self) -> list[dict]:
        """One dict per parameter for reports: name, unit, value, std, rel_std, low, high,
        start, status, note."""
        return [{"name": p.name, "unit": p.unit, "value": p.value, "std": p.std,
                 "rel_std": p.rel_std, "low": p.low, "high": p.high, "start": p.start,
                 "status": p.status, "note": p.note} for p in self.parameters]


# --------------------------------------------------------------------------- helpers


def _nearest(name: str, options: Iterable[str]) -> str:
    options = list(options)
    close = nearest(name, options, cutoff=0.5)
    return f"did you mean {', '.join(close)}?" if close else f"known: {', '.join(options)}"


def get_template(name: str) -> Template:
    """The template registered as ``name``; a ValueError names the nearest ones.

    >>> get_template("dc_motr")
    Traceback (most recent call last):
    ...
    ValueError: unknown template 'dc_motr' (did you mean dc_motor?)
    """
    try:
        return TEMPLATES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown template {name!r} ({_nearest(str(name), TEMPLATES)})") from None


def _resolve_settings(template: Template, settings: Mapping[str, str] | None) -> dict[str, str]:
    given = dict(settings or {})
    known = {s.name: s for s in template.settings}
    for key, value in given.items():
        if key not in known:
            raise ValueError(f"template {template.name} has no setting {key!r} "
                             f"({_nearest(key, known)})")
        if value not in known[key].choices:
            raise ValueError(f"template {template.name}: setting {key} must be one of "
                             f"{', '.join(known[key].choices)}, got {value!r}")
    return {s.name: given.get(s.name, s.default) for s in template.settings}


def _rk4(template: Template, theta: np.ndarray, x: np.ndarray, u: np.ndarray, dt: float,
         substeps: int) -> np.ndarray:
    """(N, n) the state one period after x (N, n) with u (N, p) held: RK4, all rows at once;
    the template's discrete rows are set by its discrete_step."""
    h = dt / substeps
    ode = template.ode
    x1 = np.asfortranarray(x)  # a state's column contiguous: the ODE works column by column
    u = np.asfortranarray(u)
    for _ in range(substeps):
        k1 = ode(theta, x1, u)
        k2 = ode(theta, x1 + (h / 2) * k1, u)
        k3 = ode(theta, x1 + (h / 2) * k2, u)
        k4 = ode(theta, x1 + h * k3, u)
        x1 = x1 + (h / 6) * (k1 + 2 * (k2 + k3) + k4)
    if template.discrete:
        x1[:, list(template.discrete)] = template.discrete_step(theta, x, u)
    return x1


def _substeps(template: Template, theta: np.ndarray, dt: float) -> int:
    return max(10, math.ceil(dt * template.rate(theta) / MAX_RATE_STEP))


def _theta(template: Template, theta: np.ndarray | Mapping[str, float]) -> np.ndarray:
    if isinstance(theta, Mapping):
        names = template.parameter_names
        for key in theta:
            if key not in names:
                raise ValueError(f"template {template.name} has no parameter {key!r} "
                                 f"({_nearest(key, names)})")
        return np.array([float(theta.get(p.name, p.default)) for p in template.parameters])
    return check_shape("theta", theta, (len(template.parameters),), dtype=float, finite=True)


# --------------------------------------------------------------------------- templates


def _dc_ode(theta: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    Rf, Lf, Ra, La, M, J, D = theta
    i_f, i_a, w, V = x[:, 0], x[:, 1], x[:, 2], u[:, 0]
    dx = np.empty_like(x)  # keeps x's memory order: columns are contiguous in _rk4
    dx[:, 0] = (V - Rf * i_f) / Lf
    dx[:, 1] = (V - Ra * i_a - M * i_f * w) / La
    dx[:, 2] = (M * i_f * i_a - D * w) / J
    return dx


def _dc_linear(theta: np.ndarray, dt: float, present: tuple[str, ...],
               settings: Mapping[str, str]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    Rf, Lf, Ra, La, _M, J, D = theta
    A = np.diag([-Rf / Lf, -Ra / La, -D / J])
    B = np.array([[1 / Lf], [1 / La], [0.0]])
    F = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    Ad, BFd = zoh(A, np.hstack([B, F]), dt)
    return Ad, BFd[:, :1], np.eye(3), BFd[:, 1:]


def _dc_rate(theta: np.ndarray) -> float:
    Rf, Lf, Ra, La, _M, J, D = theta
    return max(Rf / Lf, Ra / La, D / J)


_SERVO_STATES = ("current_setpoint", "current", "velocity", "position")


def _servo_ode(theta: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    Kt, tau, J, b = theta
    iq, w, T = x[:, 1], x[:, 2], u[:, 0]
    dx = np.empty_like(x)
    dx[:, 0] = 0.0  # the echo is a discrete row
    dx[:, 1] = (T / Kt - iq) / tau
    dx[:, 2] = (Kt * iq - b * w) / J
    dx[:, 3] = w
    return dx


def _servo_echo(theta: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    return u[:, :1] / theta[0]


def _servo_linear(theta: np.ndarray, dt: float, present: tuple[str, ...],
                  settings: Mapping[str, str]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    Kt, tau, J, b = theta
    # [Iq, omega, theta] in SI; u = T (Nm); w = load torque (Nm, opposing the motor).
    Ac = np.array([[-1 / tau, 0.0, 0.0], [Kt / J, -b / J, 0.0], [0.0, 1.0, 0.0]])
    Bc = np.array([[1 / (Kt * tau)], [0.0], [0.0]])
    Fc = np.array([[0.0], [-1 / J], [0.0]])
    Ad3, BFd3 = zoh(Ac, np.hstack([Bc, Fc]), dt)
    A, B, F = np.zeros((4, 4)), np.zeros((4, 1)), np.zeros((4, 1))
    A[1:, 1:], B[1:], F[1:] = Ad3, BFd3[:, :1], BFd3[:, 1:]
    B[0, 0] = 1 / Kt  # the echo: Iq_sp(k+1) = u(k) / Kt
    s = 1 / _servo_scale(settings)  # SI -> the drive's units
    A, B, F = s[:, None] * A / s[None, :], s[:, None] * B, s[:, None] * F
    keep = [i for i, role in enumerate(_SERVO_STATES) if role in present]
    return A[np.ix_(keep, keep)], B[keep], np.eye(len(keep)), F[keep]


def _servo_rate(theta: np.ndarray) -> float:
    _Kt, tau, J, b = theta
    return max(1 / tau, b / J)


def _servo_scale(settings: Mapping[str, str]) -> np.ndarray:
    k = 2 * math.pi if settings.get("unit", "turn") == "turn" else 1.0
    return np.array([1.0, 1.0, k, k])


TEMPLATES: dict[str, Template] = {
    "dc_motor": Template(
        name="dc_motor",
        description="Shunt-field DC motor (Chan et al. 2006, eq. 42): x = [i_f, i_a, omega], "
                    "u = V; the bilinear terms and the load torque are the unknown inputs",
        inputs=("voltage",),
        outputs=("field_current", "armature_current", "speed"),
        optional=frozenset(),
        parameters=(
            Parameter("R_f", "ohm", 52.573, 1.0, 1000.0, "field resistance"),
            Parameter("L_f", "H", 4.2059, 0.05, 100.0, "field inductance"),
            Parameter("R_a", "ohm", 3.8408, 0.05, 100.0, "armature resistance"),
            Parameter("L_a", "H", 0.10109, 1e-3, 10.0, "armature inductance"),
            Parameter("M", "H", 0.2, 1e-3, 10.0, "mutual inductance (field to armature)"),
            Parameter("J", "kg m^2", 0.05, 1e-4, 100.0, "moment of inertia of rotor and load"),
            Parameter("D", "N m s", 0.026068, 1e-5, 100.0, "viscous damping"),
        ),
        # phi1 = -(M/L_a) i_f omega (A/s, into i_a), phi2 = (M i_f i_a - T_L)/J (rad/s^2,
        # into omega): Chan et al. 2006's w, with the load torque in phi2.
        unknown_inputs=("phi1", "phi2"),
        ode=_dc_ode,
        disturbed_rows=(2,),
        linear_model=_dc_linear,
        rate=_dc_rate,
    ),
    "servo_axis": Template(
        name="servo_axis",
        description="Servo axis in torque control (ODrive-like): x = [Iq_sp, Iq, omega, theta], "
                    "u = T; the load torque and Coulomb friction are the unknown input",
        inputs=("torque",),
        outputs=_SERVO_STATES,
        optional=frozenset({"current_setpoint", "position"}),
        parameters=(
            Parameter("Kt", "N m/A", 0.08, 0.002, 5.0, "torque constant"),
            Parameter("tau_i", "s", 0.008, 1e-4, 0.5, "time constant of the closed current loop"),
            Parameter("J", "kg m^2", 5e-4, 1e-7, 10.0, "moment of inertia of rotor and load"),
            Parameter("b", "N m s/rad", 1e-4, 1e-8, 1.0, "viscous friction"),
        ),
        unknown_inputs=("load_torque",),
        ode=_servo_ode,
        disturbed_rows=(2, 3),
        linear_model=_servo_linear,
        rate=_servo_rate,
        discrete=(0,),
        discrete_step=_servo_echo,
        settings=(Setting("unit", "turn", ("turn", "rad"),
                          "velocity and position in turns/s and turns, or rad/s and rad"),),
        si_scale=_servo_scale,
    ),
}


# --------------------------------------------------------------------------- the fit


@dataclass
class _Problem:
    """The data of a fit, arranged once: everything the error function needs."""

    template: Template
    dt: float
    substeps: int
    start: np.ndarray  # (d,) full theta; free entries are exp(phi)
    free: np.ndarray  # (d_free,) indices
    X: np.ndarray  # (N, n) measured states (SI; absent roles zero, NaN where lost)
    rows: np.ndarray  # the present roles' state rows
    U: np.ndarray  # (N, p)
    x0: np.ndarray  # (K, n) measured complete states at the base samples (SI)
    u0: np.ndarray  # (K, p)
    x1: np.ndarray  # (K, n) measured next states (SI, NaN where missing or absent)
    base: np.ndarray  # (K,) sample indices k of x0
    steps: int  # N - 1
    differenced: np.ndarray  # (n,) bool
    weight: np.ndarray  # (n,) the rows' error standard deviations (SI)
    evaluations: int = 0

    def theta(self, phi: np.ndarray) -> np.ndarray:
        th = self.start.copy()
        th[self.free] = np.exp(phi)
        return th

    def errors(self, theta: np.ndarray) -> np.ndarray:
        """(N-1, n) one-step errors, SI, not differenced; NaN where there is none."""
        self.evaluations += 1
        E = np.full((self.steps, self.x0.shape[1]), np.nan)
        E[self.base] = self.x1 - _rk4(self.template, theta, self.x0, self.u0, self.dt,
                                      self.substeps)
        return E

    def fitted(self, E: np.ndarray) -> np.ndarray:
        """(N-1, n) the fitted errors: differenced rows differenced, divided by the weight."""
        R = E.copy()
        d = self.differenced
        R[1:, d] = E[1:, d] - E[:-1, d]
        R[0, d] = np.nan
        return R / self.weight

    def grid(self, phi: np.ndarray) -> np.ndarray:
        return self.fitted(self.errors(self.theta(phi)))


def _instruments(prob: _Problem, theta: np.ndarray) -> _Problem:
    """The problem whose sensitivities are the instruments: the measured states replaced by
    x_hat(k | k-2), the state predicted two periods ahead from the measured x(k-2), which
    carries the noise of y(k-2) but not that of y(k-1), y(k), y(k+1), which a (differenced)
    error e(k) holds. The commands stay: they are taken as free of the measurement noise (see
    the module's notes on a loop closed on noisy measurements)."""
    N, n = prob.X.shape
    P1 = np.full((N, n), np.nan)
    P1[prob.base + 1] = _rk4(prob.template, theta, prob.x0, prob.u0, prob.dt, prob.substeps)
    k = np.flatnonzero(np.isfinite(P1[:-1]).all(axis=1))
    P2 = np.full((N, n), np.nan)
    P2[k + 1] = _rk4(prob.template, theta, P1[k], prob.U[k], prob.dt, prob.substeps)
    prob.evaluations += 2
    return replace(prob, x0=P2[prob.base], evaluations=0)


def _floor(std: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Keep a weight away from zero (an exact row: a setpoint echo)."""
    return np.maximum(np.nan_to_num(std, nan=1.0), np.maximum(1e-9 * level, 1e-300))


def _vector(R: np.ndarray, mask: np.ndarray) -> np.ndarray:
    v = R[mask]
    return np.where(np.isfinite(v), v, 1e8)  # a diverged integration: a large, finite error


def _jacobian(prob: _Problem, phi: np.ndarray) -> np.ndarray:
    """(N-1, n, d_free) central differences of the fitted error grid."""
    J = np.empty((prob.steps, prob.x0.shape[1], phi.size))
    for j in range(phi.size):
        up, down = phi.copy(), phi.copy()
        up[j] += FD_STEP
        down[j] -= FD_STEP
        J[:, :, j] = (prob.grid(up) - prob.grid(down)) / (2 * FD_STEP)
    return J


def _check_roles(template: Template, roles: Mapping[str, int], q: int) -> None:
    for role, col in roles.items():
        if role not in template.outputs:
            raise ValueError(f"template {template.name} has no output role {role!r} "
                             f"({_nearest(role, template.outputs)})")
        if isinstance(col, bool) or not isinstance(col, int | np.integer) or not 0 <= col < q:
            raise ValueError(f"roles[{role!r}]: expected a column of Y in 0..{q - 1}, got {col!r}")
    missing = [r for r in template.outputs if r not in roles and r not in template.optional]
    if missing:
        raise ValueError(f"missing role {missing[0]!r}: template {template.name} needs "
                         f"{', '.join(r for r in template.outputs if r not in template.optional)}"
                         f" (optional: {', '.join(sorted(template.optional)) or 'none'})")
    if len(set(roles.values())) != len(roles):
        raise ValueError("roles: two roles map to the same column of Y")


def _start_values(template: Template, start: Mapping[str, float] | None,
                  fixed: Iterable[str]) -> tuple[np.ndarray, list[int]]:
    names = template.parameter_names
    theta = _theta(template, dict(start or {}))
    fixed = list(fixed)
    for name in fixed:
        if name not in names:
            raise ValueError(f"fixed parameter {name!r} is not a parameter of template "
                             f"{template.name} ({_nearest(name, names)})")
    for p, value in zip(template.parameters, theta, strict=True):
        if not (np.isfinite(value) and p.lower <= value <= p.upper):
            raise ValueError(f"start value of {p.name} = {value:g} {p.unit} is outside its "
                             f"bounds [{p.lower}, {p.upper}]")
    return theta, [names.index(n) for n in fixed]


def _ls(prob: _Problem, phi: np.ndarray, mask: np.ndarray, bounds: tuple):
    return _scipy_least_squares(lambda f: _vector(prob.grid(f), mask), phi, bounds=bounds,
                                method="trf", loss="soft_l1", f_scale=3.0, x_scale=1.0,
                                xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200 * phi.size)


def _solve(prob: _Problem, phi0: np.ndarray, noise_given: bool
           ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Least squares, reweighted until the row weights settle, then instrumental variables.

    Returns phi, its covariance (d_free, d_free) and a record of the fit."""
    lb = np.log([prob.template.parameters[i].lower for i in prob.free])
    ub = np.log([prob.template.parameters[i].upper for i in prob.free])
    phi = np.clip(phi0, lb, ub)
    iterations = 0
    mask = np.isfinite(prob.grid(phi))
    for _ in range(6):
        res = _ls(prob, phi, mask, (lb, ub))
        phi = res.x
        iterations += res.njev
        if noise_given:
            break
        new = _floor(robust_std(prob.grid(phi)) * prob.weight, prob.weight)
        ratio = new / prob.weight
        prob.weight = new
        if np.all((ratio > 0.7) & (ratio < 1.4)):
            break
    # Instrumental variables, outliers left out: z(k) is the error's sensitivity d e(k) / d phi
    # evaluated on data the noise in e(k) does not reach (see _instruments).
    R = prob.grid(phi)
    scale = _floor(robust_std(R), np.ones(R.shape[1]))
    keep = mask & (np.abs(np.nan_to_num(R, nan=np.inf)) <= OUTLIER_SIGMAS * scale)
    inst = _instruments(prob, prob.theta(phi))
    Z = np.nan_to_num(_jacobian(inst, phi)[keep])
    prob.evaluations += inst.evaluations
    Q, _ = np.linalg.qr(Z)
    res = _scipy_least_squares(lambda f: Q.T @ _vector(prob.grid(f), keep), phi,
                               bounds=(lb, ub), method="trf", x_scale=1.0, xtol=1e-12,
                               ftol=1e-14, gtol=1e-14, max_nfev=100 * phi.size)
    phi = res.x
    iterations += res.njev
    # The sandwich, with the scores' covariance from batch means over blocks of samples.
    R = prob.grid(phi)
    r = R[keep]
    Jk = _jacobian(prob, phi)[keep]
    k_index = np.nonzero(keep)[0]
    scores = Q * r[:, None]
    blocks = k_index // BLOCK
    S = np.zeros((blocks.max() + 1, phi.size))
    for j in range(phi.size):
        S[:, j] = np.bincount(blocks, weights=scores[:, j], minlength=S.shape[0])
    A = Q.T @ Jk
    Ainv = np.linalg.pinv(A)
    cov = Ainv @ (S.T @ S) @ Ainv.T
    # Singular directions of the sensitivity (columns scaled to unit norm).
    norms = np.linalg.norm(Jk, axis=0)
    sv, Vt = np.linalg.svd(Jk / np.where(norms > 0, norms, 1.0), full_matrices=False)[1:]
    singular = set()
    for s_val, v in zip(sv, Vt, strict=True):
        if not norms.any() or s_val < SINGULAR_RTOL * sv[0]:
            singular.add(int(np.argmax(np.abs(v))))
    singular |= set(np.flatnonzero(norms == 0).tolist())
    info = {"mask": keep, "iterations": iterations, "rejected": int(mask.sum() - keep.sum()),
            "cost": 0.5 * float(r @ r), "dof": max(r.size - phi.size, 1),
            "singular": sorted(singular)}
    return phi, cov, info


def _static_rows(prob: _Problem, theta: np.ndarray, Y: np.ndarray, columns: list[int],
                 rows: np.ndarray, scale: np.ndarray, extra: list[int]) -> list[StaticRow]:
    """Each extra column y_j = c . y_roles by two-stage least squares: the role outputs are
    measured with noise, so they are first projected on instruments that their noise at k does
    not reach (the one-step prediction x_hat(k | k-1) and y_roles(k-1)); plain least squares
    would shrink c (by about 2 % on the DC motor's i_f + i_a sensor)."""
    if not extra:
        return []
    N = len(Y)
    Yr = Y[:, columns]
    pred = np.full((N, len(scale)), np.nan)
    pred[prob.base + 1] = _rk4(prob.template, theta, prob.x0, prob.u0, prob.dt, prob.substeps)
    Z = np.full((N, 2 * len(columns)), np.nan)
    Z[:, : len(columns)] = pred[:, rows] / scale[rows]
    Z[1:, len(columns):] = Yr[:-1]
    Z = np.where(np.isfinite(Yr).all(axis=1, keepdims=True), Z, np.nan)
    first = least_squares(np.nan_to_num(Z, nan=0.0), np.nan_to_num(Yr, nan=0.0),
                          weights=np.isfinite(Z).all(axis=1).astype(float))
    Xhat = np.where(np.isfinite(Z).all(axis=1, keepdims=True), Z @ first.theta, np.nan)
    out = []
    for col in extra:
        second = least_squares(Xhat, Y[:, col])
        c = second.theta
        e = Y[:, col] - Yr @ c
        e = e[np.isfinite(e) & np.isfinite(Xhat).all(axis=1)]
        s2 = float(e @ e) / max(e.size - c.size, 1)
        out.append(StaticRow(col, c, np.sqrt(s2 * np.diag(second.covariance)), math.sqrt(s2)))
    return out


def fit_template(template: Template | str, U: np.ndarray, Y: np.ndarray,
                 roles: Mapping[str, int], dt: float, start: Mapping[str, float] | None = None,
                 fixed: Iterable[str] = (), noise_std: np.ndarray | None = None,
                 settings: Mapping[str, str] | None = None,
                 max_rel_std: float = MAX_REL_STD) -> TemplateFit:
    """Fit a template's parameters to a healthy log by one-step prediction error.

    Parameters
    ----------
    template : a Template or its name in `TEMPLATES`.
    U : (N, p) commands on a regular grid (p = len(template.inputs)); never NaN.
    Y : (N, q) measurements, NaN where a sample was lost.
    roles : output role -> column of Y; every role that is not optional must be present. Y's
        other columns are fitted as static relations to the roles (``static_rows``).
    dt : the sample period in seconds.
    start : parameter name -> start value (default: the datasheet value).
    fixed : names of parameters held at their start value.
    noise_std : (q,) the sensors' noise standard deviations in output units (weights of the
        rows; default: estimated from the residuals, robustly, starting at the start values).
    settings : the template's settings (e.g. ``{"unit": "rad"}`` for the servo axis).
    max_rel_std : a parameter whose relative standard deviation exceeds this is not
        determined.

    Returns
    -------
    TemplateFit.

    Raises
    ------
    ValueError : an unknown template, role, parameter or setting (with the nearest names), a
        missing role, a start value outside its bounds, too few usable samples (fewer than 10
        per free parameter), or arrays of the wrong shape.
    """
    template = get_template(template) if isinstance(template, str) else template
    conf = _resolve_settings(template, settings)
    U_a = check_shape("U", U, ("N", len(template.inputs)), dtype=float, finite=True)
    Y_a = check_shape("Y", Y, (len(U_a), "q"), dtype=float)
    if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive number of seconds, got {dt!r}")
    N, q = Y_a.shape
    n = len(template.outputs)
    _check_roles(template, roles, q)
    theta0, held = _start_values(template, start, fixed)
    noise = None if noise_std is None else check_shape("noise_std", noise_std, (q,),
                                                       dtype=float, finite=True)
    if noise is not None and np.any(noise < 0):
        raise ValueError("noise_std: must be non-negative")

    present = tuple(r for r in template.outputs if r in roles)
    rows = np.array([template.outputs.index(r) for r in present])
    scale = template.scale(conf)
    X = np.zeros((N, n))
    X[:, rows] = Y_a[:, [roles[r] for r in present]] * scale[rows]
    complete = np.isfinite(X).all(axis=1)
    base = np.flatnonzero(complete[:-1])
    x1 = np.full((N - 1, n), np.nan)
    x1[:, rows] = X[1:, rows]
    x1 = x1[base]
    differenced = np.zeros(n, dtype=bool)
    differenced[list(template.disturbed_rows)] = True
    pairs = int((np.isfinite(x1).any(axis=1)).sum())

    free = [i for i in range(len(template.parameters)) if i not in held]
    if pairs < SAMPLES_PER_PARAMETER * max(len(free), 1):
        raise ValueError(f"too few usable samples: {pairs} one-step pairs with a complete "
                         f"measured state, need at least {SAMPLES_PER_PARAMETER} per free "
                         f"parameter ({SAMPLES_PER_PARAMETER * max(len(free), 1)})")

    level = np.sqrt(np.nanmean(X[:, rows] ** 2, axis=0))
    level_n = np.ones(n)
    level_n[rows] = np.where(level > 0, level, 1.0)
    prob = _Problem(template=template, dt=float(dt), substeps=_substeps(template, theta0, dt),
                    start=theta0, free=np.array(free, dtype=int), X=X, rows=rows, U=U_a,
                    x0=X[base], u0=U_a[base], x1=x1, base=base, steps=N - 1,
                    differenced=differenced, weight=np.ones(n))
    if noise is not None:
        sensor = np.ones(n)
        sensor[rows] = noise[[roles[r] for r in present]] * scale[rows]
        prob.weight = _floor(sensor * np.where(differenced, math.sqrt(6), math.sqrt(2)),
                             level_n)
    else:
        prob.weight = _floor(robust_std(prob.fitted(prob.errors(theta0))), level_n)

    undetermined: dict[int, float] = {}
    iterations = 0
    phi = np.log(theta0[free])
    cov = np.zeros((0, 0))
    info: dict = {"cost": 0.0, "dof": 1, "rejected": 0, "mask": None}
    while prob.free.size:
        phi, cov, info = _solve(prob, phi, noise is not None)
        iterations += info["iterations"]
        needed = _substeps(template, prob.theta(phi), dt)
        if needed > prob.substeps:  # the fit went where the integrator needs finer steps
            prob.substeps = needed
            continue
        rel = np.sqrt(np.maximum(np.diag(cov), 0.0))
        bad = list(info["singular"]) or [j for j in range(phi.size) if rel[j] > max_rel_std]
        if not bad:
            break
        worst = max(bad, key=lambda j: rel[j])
        undetermined[int(prob.free[worst])] = math.inf if worst in info["singular"] else rel[worst]
        keep = [j for j in range(phi.size) if j != worst]
        prob.free, phi = prob.free[keep], phi[keep]
    theta = prob.theta(phi) if prob.free.size else theta0
    if not prob.free.size:  # nothing to fit (all fixed or not determined): the start's figures
        R = prob.fitted(prob.errors(theta))
        r = R[np.isfinite(R)]
        cov = np.zeros((0, 0))
        info = {"cost": 0.5 * float(r @ r), "dof": max(r.size, 1), "rejected": 0}

    d = len(template.parameters)
    log_cov = np.zeros((d, d))
    log_cov[np.ix_(prob.free, prob.free)] = cov
    estimates = []
    for i, p in enumerate(template.parameters):
        value = float(theta[i])
        if i in prob.free:
            s = math.sqrt(max(log_cov[i, i], 0.0))
            estimates.append(ParameterEstimate(
                p.name, p.unit, value, value * s, value * math.exp(-1.96 * s),
                value * math.exp(1.96 * s), float(theta0[i]), "estimated"))
        elif i in undetermined:
            s = undetermined[i]
            why = ("a singular direction of the Jacobian" if math.isinf(s)
                   else f"relative standard deviation {s:.3g} > {max_rel_std:g}")
            estimates.append(ParameterEstimate(
                p.name, p.unit, value, value * s, p.lower, p.upper, float(theta0[i]),
                "not determined", f"not determined by the data ({why}): held at its start "
                "value"))
        else:
            estimates.append(ParameterEstimate(p.name, p.unit, value, 0.0, value, value,
                                               float(theta0[i]), "fixed", "held by the caller"))

    E = prob.errors(theta)
    residuals = np.full((N, n), np.nan)
    residuals[1:] = E / scale
    row_std = robust_std(prob.fitted(E)) * prob.weight / scale
    row_std[[i for i in range(n) if i not in rows]] = np.nan

    A, B, C_roles, F = template.linear_model(theta, float(dt), present, conf)
    C = np.zeros((q, len(present)))
    C[[roles[r] for r in present]] = C_roles
    extra = [c for c in range(q) if c not in roles.values()]
    static = _static_rows(prob, theta, Y_a, [roles[r] for r in present], rows, scale, extra)
    for s_row in static:
        C[s_row.column] = s_row.row
    model = StateSpace(A=A, B=B, C=C, F=F, dt=float(dt))
    for array in (log_cov, residuals, row_std, *(r.row for r in static), *(r.std for r in static)):
        array.setflags(write=False)
    return TemplateFit(
        template=template, settings=conf, parameters=tuple(estimates), log_covariance=log_cov,
        model=model, states=present, unknown_inputs=template.unknown_inputs,
        static_rows=tuple(static), residuals=residuals, row_std=row_std, cost=info["cost"],
        residual_variance=2 * info["cost"] / info["dof"], samples=pairs,
        rejected=info["rejected"], iterations=iterations, evaluations=prob.evaluations,
        substeps=prob.substeps)
