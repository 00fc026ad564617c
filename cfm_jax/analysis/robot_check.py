"""``cfm-jax robot check`` (:func:`check`) and what it reports of a robot's joints
(:func:`dynamics`); above the robots and the tasks, so that :mod:`cfm_jax.sim` imports no
task."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from cfm_jax import config as config_lib
from cfm_jax import tasks as tasks_lib
from cfm_jax.learning import algorithm
from cfm_jax.sim import robots
from cfm_jax.sim.robots import Robot
from cfm_jax.tasks import babbling, baselines


@dataclasses.dataclass(frozen=True)
class Check:
    """What :func:`check` found in an MJCF file.

    Attributes:
      text: the report (what ``cfm-jax robot check`` prints).
      tasks: ``{task: None or why it cannot run}`` (``inverse_dynamics``, ``opspace``, ...).
      robot: the :class:`Robot` as the library loads it, or None.

    Examples:
      >>> check("iiwa14").tasks["opspace"] is None
      True
    """

    text: str
    tasks: dict
    robot: Robot | None

    @property
    def ok(self) -> bool:
        """Whether at least the ``inverse_dynamics`` task can run."""
        return self.tasks["inverse_dynamics"] is None


def _limit_text(model, a) -> str:
    bound = robots.actuator_torque_limit(model, a)
    if bound is None:
        return "no torque limit"
    return f"torque limit {bound[0]:g} ({bound[1]})"


@dataclasses.dataclass(frozen=True)
class Dynamics:
    """What the actuated joints of a fixed-base robot can do at its start pose.

    Attributes:
      joints: names of the actuated joints.
      effective_inertia: ``1 / (M^-1)_ii``: the inertia joint ``i`` feels with the others free.
      limit_acceleration: ``|M^-1| @ limit`` (rad/s^2): what the torque limits can give.
      noise_acceleration: std of each joint's acceleration under the babbling noise.
      noise_velocity: std of each joint's velocity change over one control period from rest.
      pd_number: ``kd dt lambda_max(diag(M) M^-1)``, the PD-only feedback's damping per
        control period in its fastest mode, with neither the joints' damping nor the sub-steps.
      babbling_pd_number: the same for the babbling's feedback, the largest over its poses.
      pd_radius: the spectral radius of the PD-only loop at the start pose over one control
        period (:func:`cfm_jax.tasks.baselines.pd_loop_radius`): stable below 1.
      babbling_pd_radius: the same for the babbling's feedback, the largest over its poses.
      babbling_damped: the joints whose babbling stiffness their damping sets.

    Examples:
      >>> round(dynamics(robots.load("iiwa14"), 0.1, kd=20.0, control_dt=0.01).pd_number, 2)
      0.27
    """

    joints: tuple[str, ...]
    effective_inertia: np.ndarray
    limit_acceleration: np.ndarray
    noise_acceleration: np.ndarray
    noise_velocity: np.ndarray
    pd_number: float
    babbling_pd_number: float
    pd_radius: float
    babbling_pd_radius: float
    babbling_damped: tuple[str, ...] = ()


def dynamics(
    robot: Robot,
    babbling_noise: float,
    kd: float,
    control_dt: float,
    torque_scale: str = "inertia",
    frequency: float = np.inf,
    kp: float = 100.0,
) -> Dynamics:
    """The :class:`Dynamics` of ``robot``'s actuated joints at ``robot.home`` (MuJoCo C).

    Args:
      robot: a loaded :class:`Robot`.
      babbling_noise: ``Config.loop.babbling_noise`` (a fraction of the torque scale).
      kd: ``Config.task.kd`` (1/s).
      control_dt: the control period (s).
      torque_scale: ``Config.loop.torque_scale`` (:data:`cfm_jax.config.TORQUE_SCALES`).
      frequency: the task's feedback frequency (rad/s); ``inf`` leaves damping out.
      kp: ``Config.task.kp`` (1/s^2), for the loops' radii.

    Examples:
      >>> dynamics(robots.load("two_link_arm"), 0.1, kd=20.0, control_dt=0.01).joints
      ('shoulder', 'elbow')
    """
    model = robot.mj_model
    full = robot.mass_matrix(robot.home)
    dofs = np.asarray(robot.actuated_dofs)
    inverse = np.linalg.inv(full)[np.ix_(dofs, dofs)]
    limit = np.asarray(robot.torque_limit, np.float64)
    if torque_scale in config_lib.COUPLED_NOISE_SCALES:  # the babbling's noise is T n at home
        noise = babbling_noise * robot.coupled_torque_scale(frequency)  # torque T n
    else:
        scale = robot.torque_scale(frequency) if torque_scale == "inertia" else limit
        noise = np.diag(babbling_noise * scale)
    coupling = np.diag(np.diag(full)[dofs]) @ inverse
    joints = tuple(robot.joint_names[int(model.dof_jntid[d])] for d in dofs)
    poses = babbling.pose_sample(robot, robot.home)
    # M(q)^-1 at the babbling's poses: the lightest inertia and the loop's number.
    inverses = np.linalg.inv(robot.mass_matrices(poses))
    lightest = robot.lightest_inertia(poses)
    babbling_number = np.abs(
        np.linalg.eigvals(np.diag(lightest) @ inverses[:, dofs][:, :, dofs])
    ).max()
    diagonal = np.diag(full)[dofs]
    radius = baselines.pd_loop_radius(robot, kp * diagonal, kd * diagonal, robot.home, control_dt)
    gain_p, gain_d = baselines.babbling_joint_gains(robot, kp, kd, poses)
    babbling_radius = max(
        baselines.pd_loop_radius(robot, gain_p, gain_d, q, control_dt) for q in poses
    )
    # Over a control period the joints' damping acts as (M + h D)^-1 (MuJoCo's implicit
    # damping): the velocity a held torque gives in one period.
    damped = np.linalg.inv(full + control_dt * np.diag(model.dof_damping))[np.ix_(dofs, dofs)]
    return Dynamics(
        joints=joints,
        effective_inertia=1.0 / np.diag(inverse),
        limit_acceleration=np.abs(inverse) @ limit,
        noise_acceleration=np.sqrt(np.diag(inverse @ noise @ noise.T @ inverse)),
        noise_velocity=control_dt * np.sqrt(np.diag(damped @ noise @ noise.T @ damped.T)),
        pd_number=float(kd * control_dt * np.max(np.abs(np.linalg.eigvals(coupling)))),
        babbling_pd_number=float(kd * control_dt * babbling_number),
        pd_radius=radius,
        babbling_pd_radius=babbling_radius,
        babbling_damped=tuple(n for n, p in zip(joints, gain_p > kp * lightest, strict=True) if p),
    )


def _dynamics_lines(robot: Robot) -> list[str]:
    """The report's lines on :func:`dynamics` at the defaults, with warnings."""
    task, loop = config_lib.TaskConfig(), config_lib.LoopConfig()
    dt = task.control_period(robot.timestep)
    frequency = task.feedback_frequency(dt)
    d = dynamics(robot, loop.babbling_noise, task.kd, dt, loop.torque_scale, frequency, task.kp)
    kind = algorithm.scale_kind(config_lib.Config(loop=loop), robot)
    why = "MJX builds it" if kind == "pose" else "MJX cannot build it; pose needs MJX"
    lines = [
        f"torque scale: loop.torque_scale {loop.torque_scale!r} gives {kind!r} here ({why}; "
        "docs/results/torque_scale_decision.md)",
        f"dynamics at the start pose (defaults: loop.babbling_noise {loop.babbling_noise:g} "
        f"of the torque scale, at home, at the feedback's "
        f"{frequency:g} rad/s, task.kd {task.kd:g} 1/s, control period {dt:g} s):",
    ]
    for j, name in enumerate(d.joints):
        lines.append(
            f"  {name}: effective inertia {d.effective_inertia[j]:.3g}, torque limit gives "
            f"{d.limit_acceleration[j]:.3g} rad/s^2, babbling noise {d.noise_acceleration[j]:.3g}"
            f" rad/s^2 at rest, {d.noise_velocity[j]:.3g} rad/s per control period (std)"
        )
    lines.append(
        "  PD-only baseline's feedback (torque gains task.kp, task.kd x diag M(home)): its loop's "
        f"radius over a control period at the start pose {d.pd_radius:.4f} (stable below 1; "
        f"kd * dt * lambda_max(diag(M) M^-1) = {d.pd_number:.2f}); the babbling's feedback: its "
        f"largest radius over the poses it visits {d.babbling_pd_radius:.4f}"
        + (
            f"; its stiffness is sqrt(kp) x damping on {', '.join(d.babbling_damped)} (their "
            "damping outweighs their inertia)"
            if d.babbling_damped
            else ""
        )
    )
    if d.pd_radius >= 1:
        lines.append(
            "  ! the PD-only baseline's feedback is unstable at the start pose at this control "
            f"period (radius {d.pd_radius:.3g} >= 1): its torque gains are kd * diag M(home), "
            "and the joints' coupling through M^-1 multiplies them. The baseline is what it "
            "is (its torque limits bound it); lower task.kd or task.control_dt for a stable "
            "one (docs/how-to/own-robot.md)."
        )
    if d.babbling_pd_radius >= 1:
        lines.append(
            "  ! the babbling's feedback is unstable at some of the poses it visits (radius "
            f"{d.babbling_pd_radius:.3g} >= 1): the initial data will oscillate. Lower "
            "task.kd or task.control_dt."
        )
    worst = int(np.argmax(d.noise_velocity))
    kick = float(d.noise_velocity[worst])
    if kick > 1.0:
        lines.append(
            f"  ! babbling noise changes {d.joints[worst]}'s velocity by about {kick:.3g} "
            f"rad/s per control period ({d.noise_acceleration[worst]:.3g} rad/s^2 at rest): "
            "the initial data will be dominated by noise that no tracking motion asks for. "
            "Lowering loop.babbling_noise is not a known cure (on the development set's ARX "
            "L5 a tenth of it made every loss worse; docs/how-to/own-robot.md)."
        )
    return lines


def _legs_lines(robot: Robot) -> list[str]:
    """The report's lines on a floating-base robot's legs
    (:func:`cfm_jax.sim.quadruped.describe`)."""
    from cfm_jax.sim import quadruped

    try:
        found = quadruped.describe(robot.mj_model)
    except quadruped.QuadrupedError as error:
        return [f"quadruped: no: {error}"]
    added = [f"  added at load time: {what}" for what in robot.added]
    return (
        ["quadruped: yes, read from the file (cfm_jax.sim.quadruped):"]
        + ["  " + line for line in found.summary().splitlines()]
        + added
        + _jump_lines(robot)
    )


def _jump_lines(robot: Robot) -> list[str]:
    """How high the jump task's references go on this quadruped
    (:func:`cfm_jax.tasks.locomotion.jump_height_scale`); none where its legs cannot be read."""
    from cfm_jax.sim import solo12
    from cfm_jax.tasks import locomotion

    try:
        legs = locomotion.legs_of(robot.mj_model)
        scale, landed = locomotion.jump_height_scale(legs), locomotion.largest_landed_jump(legs)
        solo = locomotion.largest_landed_jump(locomotion.legs_of(solo12.load_model()))
    except (ValueError, RuntimeError) as error:
        return [f"  jump heights: not computed ({error})"]
    return [
        f"  jump heights: the Solo12's times {scale:.3f} (length scale {legs.scale:.3f}; the "
        f"highest reference jump it lands by its fall rule clears {landed:.3f} m, the "
        f"Solo12's {solo:.3f} m)"
    ]


SMALL_RANGE = 0.2
"""A hinge range narrower than this (rad, 11.5 degrees) is small for an arm's joint."""


def degrees_trap(model, path: str) -> str | None:
    """A warning when every limited hinge's range is narrower than :data:`SMALL_RANGE` and
    the file reads angles in degrees (MuJoCo's default without ``<compiler
    angle="radian"/>``): ranges meant as radians became degrees. None otherwise.

    Args:
      model: the compiled ``mujoco.MjModel``.
      path: its MJCF file (for the compiler's angle unit).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> degrees_trap(robots.load("iiwa14").mj_model, robots.resolve("iiwa14")) is None
      True
    """
    hinges = [j for j in range(model.njnt)
              if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
              and bool(model.jnt_limited[j])]  # fmt: skip
    if not hinges:
        return None
    spans = model.jnt_range[hinges, 1] - model.jnt_range[hinges, 0]
    if float(spans.max()) >= SMALL_RANGE:
        return None
    try:
        degrees = bool(mujoco.MjSpec.from_file(path).compiler.degree)
    except Exception:  # the file compiled; a spec that does not load changes nothing here
        degrees = False
    if not degrees:
        return None
    return (
        f"every hinge's range spans less than {SMALL_RANGE:g} rad (the widest "
        f"{float(spans.max()):.3g} rad = {np.degrees(float(spans.max())):.3g} degrees), and "
        'the file reads angles in degrees (no <compiler angle="radian"/>, MuJoCo\'s '
        "default): ranges written in radians became degrees. Add the compiler line if so; "
        "the reaches are drawn inside these ranges."
    )


def check(name_or_path: str, actuators: str = "strict", torque_limit=None) -> Check:
    """Load a file as the library would; report what it found and which tasks can run.

    Args:
      name_or_path: registered name or MJCF path.
      actuators: ``Config.robot_actuators`` (one of :data:`cfm_jax.sim.robots.ACTUATORS`).
      torque_limit: ``Config.robot_torque_limit``.

    Raises:
      robots.RobotError: the file does not exist or does not parse.

    Examples:
      >>> found = check("two_link_arm")
      >>> found.ok, found.tasks["opspace"] is None
      (True, False)
    """
    from cfm_jax.config import ConfigError

    path = robots.resolve(name_or_path)
    try:
        raw = robots.compile_file(path)
    except Exception as error:
        raise robots.RobotError(
            f"robot={name_or_path!r}: MJCF file {path} does not parse: {error}"
        ) from error
    where = f"robot={name_or_path!r} ({path})"
    lines = [f"robot {name_or_path} ({path})", f"joints ({raw.njnt}):"]
    for j in range(raw.njnt):
        kind = mujoco.mjtJoint(int(raw.jnt_type[j])).name[len("mjJNT_") :].lower()
        limited = bool(raw.jnt_limited[j])
        rng = f"range [{raw.jnt_range[j, 0]:g}, {raw.jnt_range[j, 1]:g}]" if limited else "no range"
        lines.append(f"  {robots.joint_name(raw, j)}: {kind}, {rng}")
    trap = degrees_trap(raw, path)
    if trap:
        lines.append(f"  ! {trap}")
    held, keep = robots.held_joints(raw)
    try:
        servos = robots.servo_limits(raw, torque_limit, where, keep)
        servo_error = None
    except robots.RobotError as error:
        servos, servo_error = {}, str(error)
    lines.append(f"actuators ({raw.nu}):")
    for a in range(raw.nu):
        aname = mujoco.mj_id2name(raw, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}"
        if a in keep:
            lines.append(f"  {aname}: moves only held joints; kept as published, held")
            continue
        if int(raw.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            trn = mujoco.mjtTrn(int(raw.actuator_trntype[a])).name[len("mjTRN_") :].lower()
            lines.append(f"  {aname}: {trn} transmission (not usable: no joint of its own)")
            continue
        joint = robots.joint_name(raw, int(raw.actuator_trnid[a, 0]))
        kind = robots.servo_kind(raw, a)
        if kind is None:
            lines.append(f"  {aname}: motor on {joint}, {_limit_text(raw, a)}")
        elif a in servos:
            _, limit, source = servos[a]
            lines.append(
                f"  {aname}: {kind} servo on {joint}; as a torque motor: torque limit "
                f"{limit:g} ({source})"
            )
        else:
            lines.append(f"  {aname}: {kind} servo on {joint}; no torque limit found")
    if servo_error:
        lines.append(f"  ! {servo_error}")
    free = raw.njnt > 0 and int(raw.jnt_type[0]) == int(mujoco.mjtJoint.mjJNT_FREE)
    lines.append(f"floating base: {'yes' if free else 'no'}")
    sites = [
        mujoco.mj_id2name(raw, mujoco.mjtObj.mjOBJ_SITE, i) or f"#{i}" for i in range(raw.nsite)
    ]
    lines.append(f"sites: {', '.join(sites) if sites else 'none'}")
    keys = [mujoco.mj_id2name(raw, mujoco.mjtObj.mjOBJ_KEY, i) or f"#{i}" for i in range(raw.nkey)]
    start = "keyframe home" if "home" in keys else "qpos0"
    if start == "qpos0" and free:
        from cfm_jax.sim import quadruped

        try:  # a quadruped starts from its standing pose (robots.load's home)
            quadruped.describe(raw)
            start = "the quadruped's standing pose, below"
        except (quadruped.QuadrupedError, ValueError):
            pass
    lines.append(f"keyframes: {', '.join(keys) if keys else 'none'} (start pose: {start})")
    tasks: dict = {}
    robot = None
    try:
        robot = robots.load(name_or_path, actuators=actuators, torque_limit=torque_limit)
        lines.append(f"loads with robot_actuators={actuators!r}: yes")
        if robot.held_joints:
            lines.append(
                f"held joints: {', '.join(robot.held_joints)} (coupled by an equality "
                "constraint: not trained; simulated as published, their own actuators hold "
                "the home keyframe's ctrl)"
            )
        if robot.passive_joints:
            lines.append(
                f"  ! passive joints: {', '.join(robot.passive_joints)} (no actuator, no "
                "coupling: not trained, left to swing as published); if they should be "
                "driven, give each a <motor>"
            )
    except robots.RobotError as error:
        reason = str(error).replace(where + ": ", "").replace(where + " ", "")
        if actuators == "strict" and servos and servo_error is None:
            reason += " -- with robot_actuators='torque' it loads"
        lines.append(f"loads with robot_actuators={actuators!r}: no: {reason}")
        tasks = dict.fromkeys(tasks_lib.REGISTRY, reason)
        lines.append("tasks: none (the file does not load, see above)")
        return Check("\n".join(lines), tasks, None)
    notes = {}
    if robot is not None:
        for name, spec in tasks_lib.REGISTRY.items():
            try:
                notes[name] = spec.fits(robot) if spec.fits is not None else "not checked"
                tasks[name] = None
            except ConfigError as error:
                tasks[name] = str(error)
    if robot is not None:
        mjx_error = robot.mjx_error
        lines.append(
            "MJX builds it: yes"
            if mjx_error is None
            else "MJX builds it: no (the native simulator runs it): "
            + mjx_error.replace(f"robot={robot.name!r}: ", "")
        )
        if not robot.floating_base:
            lines += _dynamics_lines(robot)
        else:
            lines += _legs_lines(robot)
    lines.append("tasks:")
    for name, reason in tasks.items():
        extra = f" ({notes[name]})" if notes.get(name) else ""
        lines.append(f"  {name}: " + ("yes" + extra if reason is None else f"no: {reason}"))
    return Check("\n".join(lines), tasks, robot)


def refuse_unfit(config) -> None:
    """Refuse, before any training, a config whose robot does not load or whose task cannot
    run on it (``cfm-jax config``): the robot loaded as training loads it
    (:func:`cfm_jax.sim.robots.of_config`), then the task's ``fits``
    (:class:`cfm_jax.tasks.TaskSpec`), the check ``cfm-jax robot check`` reports.

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Raises:
      ConfigError: the task does not fit the robot (the task's reason, naming the robot).
      robots.RobotError: the robot does not load (its reason).

    Examples:
      >>> from cfm_jax.config import Config, TaskConfig
      >>> refuse_unfit(Config(robot="two_link_arm", task=TaskConfig(name="walk")))
      Traceback (most recent call last):
      cfm_jax.config.ConfigError: task.name='walk' does not fit robot='two_link_arm': ...
    """
    from cfm_jax.config import ConfigError

    robot = robots.of_config(config)  # as training loads it
    spec = tasks_lib.load(config.task.name)
    if spec.fits is None:
        return
    try:
        spec.fits(robot)
    except ConfigError as error:
        raise ConfigError(
            f"task.name={config.task.name!r} does not fit robot={config.robot!r}: {error}"
        ) from None
