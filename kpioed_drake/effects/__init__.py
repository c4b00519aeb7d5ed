"""Non-geometric effects: what the kinematic model leaves out (SPEC "Measured data and model discrepancy").

Four effect families, each a few parameters on top of the geometric parameter vector of
:mod:`kpioed_drake.robot.parameters` (joint numbers are 1-based, as in SPEC and on the command line):

============================  ============================================  ====================
family (``parse_effect``)     model                                         parameters (inside)
============================  ============================================  ====================
``joint_elasticity:i[=c]``    joint i deflects by ``c * tau_i(q)``          c [rad/(N m)]
``gear_cyclic:i:n[=a,b]``     joint i angle error ``a sin(n q_i) + b cos``  a, b [rad] (text: deg)
``thermal_expansion[=k]``     robot lengths scale by ``1 + k (T - T_ref)``  k [1/K]
``tracker_drift[=vx,vy,vz]``  tracker origin moves by ``v t`` (v in W)      v [mm/s] (text: mm/min)
``joint_scale:i[=eps]``       gear-ratio error: joint i angle ``q_i (1+eps)`` eps [1] (text: ppm)
``joint_coupling:i:j[=c]``    joint i angle error ``c q_j`` (coupled drives)  c [1] (text: ppm)
``tracker_scale[=k]``         distances from the tracker scale by           k [1/K] (text: ppm/K)
                              ``s_T = 1 + k (T - T_REF)`` (air refraction)
``backlash:i[=b]``            joint i angle error ``b sign(tau_i(q))``      b [rad] (text: deg)
``joint_elasticity_basis:i``  joint i deflects by ``Y_i(q) . theta``        theta (r_i) [rad]
                              (gravity basis: any link masses; see          (+ c_i of a varying
                              :mod:`.gravity_basis`)                        payload)
``column_compliance:k[=c]``   lift column (prismatic k) bends: all above    c = 1/EI
                              turns by ``c h M_perp`` about ``C - a h/2``   [1/(N m^2)]
``base_compliance[=c]``       soft floor/mount: the robot turns by          c [rad/(N m)]
                              ``c M_B`` about the base origin
``lateral_compliance:j[=c]``  joint j's bearing yields: all it carries      c [rad/(N m)]
                              turns by ``c (I - a a^T) M_j`` about ``a_j``
============================  ============================================  ====================

``lateral_compliance_basis:j`` is the lateral compliance with any link masses: all joint j carries
turns by ``P X_j(q) . theta``, theta (r_j) [rad] (:mod:`.lateral_basis`).

The first four (:data:`FAMILIES`) are SPEC's; the next four (:data:`EXTRA_FAMILIES`) are further
diagnosis candidates and work in simulation and ``--extend``; the gravity basis
(``joint_elasticity_basis``, also in :data:`EXTRA_FAMILIES`) works in ``--extend`` and in the
diagnosis's upgrade of a named elasticity (:mod:`kpioed_drake.diagnosis.elastic_basis`), it has no
size to draw for simulation. ``joint_scale``,
``joint_coupling`` and ``backlash`` are joint-angle effects like elasticity and gear
(:data:`JOINT_FAMILIES`): their column is joint i's theta column times the factor ``q_i``, ``q_j``
or ``sign(tau_i)``. A backlash follows the sign of the gravity torque (the data format has no
approach direction); its derivative w.r.t. q is zero almost everywhere. The tracker scale has one
parameter, its temperature part: a constant scale about the tracker is a scale of every length and
of the tracker position, which the geometric parameters absorb (as for a constant temperature of
thermal expansion), so it is not a parameter; it multiplies the whole measurement (all columns).
The compliances (:data:`COMPLIANCE_FAMILIES`, :mod:`.compliance`) are rigid rotations of what the
column or base carries, driven by the gravity moment of the links above it (model file masses,
payload included): ``M`` about the carriage point C, perpendicular to the column axis a, h the
carriage height above the column's foot; ``M_B`` about the base origin. The top leans towards the
load (c > 0). Simulation, ``--extend`` (calibrate and design) and diagnosis candidates for robots on
a lift or with ``compliant_base: true``.

Conventions (the choices SPEC leaves open, kept here in one place):

- Joint angles ``q`` in the data are the *commanded* (encoder) angles. Joint-angle effects act as
  ``q_actual = q_cmd + delta(q_cmd)``; the deflection and the gear error are evaluated at the
  commanded angles (the difference to evaluating them at ``q_actual`` is second order, below
  1e-7 rad at SPEC sizes).
- Gravity torque ``tau(q)`` [N m] is Drake's ``MultibodyPlant.CalcGravityGeneralizedForces`` on the
  plant of :func:`kpioed_drake.robot.plant.build_scene` built from the robot's *nominal* geometry, link
  masses and centres of mass (metres inside Drake). Drake returns the generalized force that
  gravity exerts on each joint (the term on the right of ``M v' + C v = tau_g + tau``), so a joint
  held by a spring of compliance c at the commanded angle settles at
  ``q_actual = q_cmd + c * tau_g``: a positive c means the joint yields in the direction gravity
  pushes it. Joint 1 of every shipped robot turns about the vertical axis: gravity has no torque
  there and elasticity of joint 1 cannot be seen (``parse_effect`` refuses it).
- Payload: a point mass ``payload_kg`` at the reflector/TCP point ``p_FQ`` of the model; its torque
  is ``J_v^T (m g)`` with ``J_v`` the translational Jacobian of that point from the numpy kinematics
  (same nominal geometry). Its joint-angle derivative is closed form (see ``_payload_torque``).
- Thermal expansion scales *every* length of the robot side by ``s = 1 + k (T - T_REF_C)``: all
  ``a`` and ``d`` of the kinematic table and the reflector offset ``p_FQ`` (the reflector holder is
  steel too). Because the reflector position is homogeneous of degree one in those lengths, this
  is exactly ``p_WQ -> s p_WQ`` (a scaling about the base origin W). The tracker position does not
  scale. ``T_REF_C`` = 20 C: the geometric parameters describe the robot at 20 C. A temperature that
  is constant over the data only rescales the geometry (absorbed by the length parameters); only its
  variation over the data identifies k.
- Tracker drift: the tracker origin moves in W as ``p_WT(t) = p_WT + v t`` (``t`` = ``time_s``).
  A constant offset is the tracker position itself; only the linear part is an effect.

Measurement model with effects (everything in the tracker frame, mm)::

    h = s_T R_TW (s * p_WQ(p, q_cmd + delta) - p_WT - v t)

:func:`true_measurements` evaluates it (noise-free) for simulation; :func:`augmented_jacobian`
returns its Jacobian w.r.t. the geometric parameters and the effect parameters (closed form,
finite-difference checked in ``tests/test_effects.py``); :func:`extension_columns` returns just the
effect columns (and their joint-angle derivative) so that calibration and design can append them to
``F1``.

Realistic sizes (SPEC), used when ``parse_effect`` draws a value with a random generator:

- elasticity: the largest tool displacement it causes over the joint box is drawn uniformly in
  0.1-1 mm (``tool_mm``); c follows from the robot (:func:`resolve`: max over 2000 seeded poses
  within the joint limits of ``|tau_i| * |dp_WQ/dq_i|``, no payload);
- gear: a and b each uniform in 0.003-0.02 deg with a random sign;
- thermal: k = 11.7e-6 /K (steel), not drawn (without ``rng``: unknown, like the others);
- drift: speed uniform in 0.005-0.05 mm/min, direction uniform on the sphere;
- joint scale and coupling: 100-1000 ppm (``SCALE_PPM``), random sign; backlash: 0.003-0.02 deg
  (``BACKLASH_DEG``), positive; tracker scale: -0.93 ppm/K (``AIR_PPM_PER_K``, not drawn);
- column and base compliance: the largest reflector displacement over the joint box drawn in
  0.1-1 mm (``COMPLIANCE_TOOL_MM``, as ``tool_mm``), c positive (:func:`resolve`).

Modules: :mod:`.model` (:class:`Effect`, the text syntax, sizes), :mod:`.gravity` (gravity and
payload torques, the elastic lever), :mod:`.gravity_basis` (the gravity torque as a combination of
identifiable mass moments: elasticity without trusting the model file's masses), :mod:`.compliance`
(column, base and lateral compliance: the rotation, its pivot and their derivatives),
:mod:`.lateral_basis` (the lateral compliance as a combination of identifiable mass moments),
:mod:`.response` (the measurement model with effects, its Jacobian, the effects' design and KPI
columns), :mod:`.physical` (the plausibility bounds of a fitted effect, per drive type),
:mod:`.stored` (an extended model file's ``effects:`` entries as effects, and back) and
:mod:`.basis_store` (the mass-free bases a robot object carries).
"""

from kpioed_drake.effects.gravity import (
    GravityModel,
    elastic_lever,
    gravity_model,
    gravity_torques,
    reference_poses,
)
from kpioed_drake.effects.model import (
    AIR_PPM_PER_K,
    ALL_FAMILIES,
    BACKLASH_DEG,
    BASIS_FAMILIES,
    COMPLIANCE_FAMILIES,
    COMPLIANCE_TOOL_MM,
    DRIFT_MM_PER_MIN,
    ELASTIC_TOOL_MM,
    EXTRA_FAMILIES,
    FAMILIES,
    GEAR_DEG,
    JOINT_FAMILIES,
    N_PARAMS,
    ROTATION_FAMILIES,
    SCALE_PPM,
    STEEL_K,
    T_REF_C,
    UNITS,
    Effect,
    parse_effect,
    parse_effects,
    resolve,
)
from kpioed_drake.effects.response import (
    augmented_jacobian,
    augmented_response,
    effect_kpi_columns,
    effect_tcp_shift,
    extension_columns,
    extension_param_names,
    joint_deltas,
    true_measurements,
)
from kpioed_drake.effects.stored import effect_specs, model_effects

__all__ = [
    "AIR_PPM_PER_K",
    "ALL_FAMILIES",
    "BACKLASH_DEG",
    "BASIS_FAMILIES",
    "COMPLIANCE_FAMILIES",
    "COMPLIANCE_TOOL_MM",
    "DRIFT_MM_PER_MIN",
    "ELASTIC_TOOL_MM",
    "EXTRA_FAMILIES",
    "FAMILIES",
    "GEAR_DEG",
    "JOINT_FAMILIES",
    "N_PARAMS",
    "ROTATION_FAMILIES",
    "SCALE_PPM",
    "STEEL_K",
    "T_REF_C",
    "UNITS",
    "Effect",
    "GravityModel",
    "augmented_jacobian",
    "augmented_response",
    "effect_kpi_columns",
    "effect_specs",
    "effect_tcp_shift",
    "elastic_lever",
    "extension_columns",
    "extension_param_names",
    "gravity_model",
    "gravity_torques",
    "joint_deltas",
    "model_effects",
    "parse_effect",
    "parse_effects",
    "reference_poses",
    "resolve",
    "true_measurements",
]
