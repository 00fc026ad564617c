"""The ``rigid_body`` forward model against MuJoCo C: with a zero residual it predicts
``mj_forward``'s ``qacc`` (free space: no contact, joints inside their limits), its
Jacobian in ``tau`` is ``M^-1 S`` (central differences of ``mj_forward``), and the nominal
mass scale scales ``M`` (the links' part) and the bias force as the closed form says."""

from __future__ import annotations

import dataclasses
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pandas as pd
import pytest
import sites
from tiny import tiny_config

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.learning import forward_models, networks, rigid_body
from cfm_jax.sim import robots


def _random_states(robot, rng, count):
    """Free-space states: joints in the middle half of their ranges (no limit active),
    a floating base 2 m above the floor (no contact), random velocities and torques."""
    m = robot.mj_model
    out = []
    for _ in range(count):
        qpos = np.array(robot.home, np.float64)
        for j in range(m.njnt):
            if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
                lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-1.0, 1.0)
                centre, half = (lo + hi) / 2, (hi - lo) / 4
                qpos[m.jnt_qposadr[j]] = centre + rng.uniform(-half, half)
        if robot.floating_base:
            quat = rng.normal(size=4)
            qpos[:3] = [0.1, -0.2, 2.0]
            qpos[3:7] = quat / np.linalg.norm(quat)
        qvel = rng.normal(size=m.nv)
        tau = rng.uniform(-1.0, 1.0, robot.action_dim) * robot.torque_limit
        out.append((qpos, qvel, tau))
    return out


def _mujoco_qacc(robot, qpos, qvel, tau, model=None):
    """``qacc`` of MuJoCo C (float64) with torques ``tau`` on the actuated joints."""
    m = robot.mj_model if model is None else model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    d.ctrl[robot.actuator_of_joint] = tau / robot.gear
    mujoco.mj_forward(m, d)
    assert d.ncon == 0 and d.nefc == 0, "the state must be in free space"
    return d.qacc.copy()


def _zero_residual(params):
    """Parameters whose ensemble mean is zero: the last layer of every member zeroed."""
    members = params["members"]["params"]
    last = sorted(members, key=lambda name: int(name.split("_")[-1]))[-1]
    zeroed = {**members, last: jax.tree.map(jnp.zeros_like, members[last])}
    return {**params, "members": {"params": zeroed}}


def _model(robot, task, **forward):
    cfg = config_lib.ForwardModelConfig(kind="rigid_body", hidden=(8,), ensemble_size=2, **forward)
    fm = forward_models.make(cfg, robot, task)
    params = _zero_residual(fm.init(jax.random.key(0), task.state_dim))
    return fm, params


def _normaliser(task, robot, rng):
    """A normaliser that is not the identity, so that the physics has to pass through it."""
    return networks.Normaliser(
        jnp.asarray(rng.normal(size=task.state_dim), jnp.float32),
        jnp.asarray(rng.uniform(0.5, 2.0, task.state_dim), jnp.float32),
        jnp.asarray(rng.normal(size=task.output_dim), jnp.float32),
        jnp.asarray(rng.uniform(0.5, 20.0, task.output_dim), jnp.float32),
        jnp.asarray(robot.torque_limit, jnp.float32),
    )


def _predict(fm, params, norm, state, tau):
    """The model's prediction in physical units, terms computed from the state."""
    terms = fm.terms(state)
    return norm.output_inverse(fm.predict(params, norm, state, tau, terms))


@pytest.fixture(scope="module")
def arms():
    out = {}
    for name in ("two_link_arm", "iiwa14"):
        robot = robots.load(name)
        out[name] = (robot, tasks.make(robot, config_lib.TaskConfig(duration=0.1), 0.01))
    return out


@pytest.mark.parametrize(
    "name",
    ["two_link_arm", pytest.param("iiwa14", marks=pytest.mark.slow)],  # iiwa: ~5 s
)
def test_zero_residual_predicts_mujoco_qacc_and_jacobian_is_inverse_mass(arms, name):
    robot, task = arms[name]
    rng = np.random.default_rng(1)
    fm, params = _model(robot, task)
    norm = _normaliser(task, robot, rng)

    def both(s, t):
        y = _predict(fm, params, norm, s, t)
        return y, y

    predict = jax.jit(jax.jacfwd(both, argnums=1, has_aux=True))  # (d y / d tau, y)
    for qpos, qvel, tau in _random_states(robot, rng, 4):
        state = jnp.asarray(np.concatenate([qpos, qvel]), jnp.float32)
        tau32 = jnp.asarray(tau, jnp.float32)
        expected = _mujoco_qacc(robot, qpos, qvel, tau)
        got_jacobian, got = (np.asarray(x) for x in predict(state, tau32))
        scale = np.max(np.abs(expected))
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-5 * scale)
        # d qacc / d tau of MuJoCo C by central differences (linear: exact up to rounding).
        eps = 1e-3 * robot.torque_limit
        columns = []
        for j in range(robot.action_dim):
            step = np.zeros(robot.action_dim)
            step[j] = eps[j]
            plus = _mujoco_qacc(robot, qpos, qvel, tau + step)
            minus = _mujoco_qacc(robot, qpos, qvel, tau - step)
            columns.append((plus - minus) / (2 * eps[j]))
        expected_jacobian = np.stack(columns, axis=1)
        np.testing.assert_allclose(
            got_jacobian, expected_jacobian, rtol=0, atol=2e-5 * np.max(np.abs(expected_jacobian))
        )


# In the default run (about 4 s of MJX compilation): the only check of the legged tasks'
# rigid-body model against MuJoCo C.
def test_solo12_in_the_air_zero_residual_is_mujoco_qacc_times_dt_then_forces():
    """The legged output ``[qacc dt, foot forces]``: the first ``nv`` entries are MuJoCo's
    ``qacc`` times the control period, the forces the residual's alone (zero here)."""
    robot = robots.load("solo12")
    dt = 0.004
    task = tasks.legged.LeggedTask.__new__(tasks.legged.LeggedTask)  # no references needed
    task.robot, task.control_dt, task.name = robot, dt, "walk"
    task.state_dim, task.output_dim, task.action_dim = robot.nq + 12 + robot.nv, robot.nv + 12, 12
    rng = np.random.default_rng(2)
    fm, params = _model(robot, task)
    norm = _normaliser(task, robot, rng)
    predict = jax.jit(lambda s, t: _predict(fm, params, norm, s, t))
    for qpos, qvel, tau in _random_states(robot, rng, 3):
        forces = rng.normal(size=12)  # carried in the state, not used by the physics
        state = jnp.asarray(np.concatenate([qpos, forces, qvel]), jnp.float32)
        got = np.asarray(predict(state, jnp.asarray(tau, jnp.float32)))
        expected = _mujoco_qacc(robot, qpos, qvel, tau) * dt
        np.testing.assert_allclose(
            got[: robot.nv], expected, rtol=0, atol=2e-5 * np.max(np.abs(expected))
        )
        # Zero residual (normalised units): the force entries are the normaliser's mean.
        np.testing.assert_allclose(got[robot.nv :], norm.output_mean[robot.nv :], atol=1e-5)


def test_nominal_mass_scale_scales_links_inertia_and_bias(arms):
    """Closed form: every body mass and inertia times c gives ``M_c = c (M - A) + A`` (``A``
    the joints' armature, not a link's) and ``qfrc_bias`` times c; the stored terms are
    ``M_c^-1 S`` and, at rest (no damping force), ``-M_c^-1 qfrc_bias_c``."""
    robot, _ = arms["two_link_arm"]
    assert np.all(robot.mj_model.dof_armature > 0)  # so that the closed form tells them apart
    c = 1.7
    rng = np.random.default_rng(3)
    (qpos, _, _), *_ = _random_states(robot, rng, 1)
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    mass = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, mass)
    armature = np.diag(m.dof_armature)
    mass_c = c * (mass - armature) + armature
    bias_c = c * d.qfrc_bias
    scaled = rigid_body.nominal_model(robot, mass_scale=c)
    # MuJoCo C on the scaled model agrees with the closed form.
    ds = mujoco.MjData(scaled)
    ds.qpos[:] = qpos
    mujoco.mj_forward(scaled, ds)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(scaled, ds, full)
    np.testing.assert_allclose(full, mass_c, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ds.qfrc_bias, bias_c, rtol=1e-12, atol=1e-12)
    # The model's stored terms are those of the scaled model.
    terms = jax.jit(
        rigid_body.terms_function(
            scaled, robot.actuated_dofs, lambda s: (s[..., : m.nq], s[..., m.nq :])
        )
    )(jnp.asarray(np.concatenate([qpos, np.zeros(m.nv)]), jnp.float32))
    inverse = np.linalg.inv(mass_c)
    np.testing.assert_allclose(terms.gain, inverse[:, robot.actuated_dofs], rtol=2e-4, atol=1e-4)
    np.testing.assert_allclose(terms.drift, -inverse @ bias_c, rtol=2e-4, atol=1e-3)
    # The robot's own model is not changed by building the nominal one.
    assert m.body_mass[1] == robots.load("two_link_arm").mj_model.body_mass[1]


def test_nominal_file_must_have_the_robots_joints(arms):
    robot, task = arms["two_link_arm"]
    with pytest.raises(config_lib.ConfigError, match=r"forward\.options\.nominal='iiwa14'"):
        _model(robot, task, options={"nominal": "iiwa14"})


def test_a_task_whose_output_is_not_affine_in_qacc_is_refused():
    robot = robots.load("two_link_arm")
    task = types.SimpleNamespace(name="custom", acceleration_output=lambda: None)
    with pytest.raises(config_lib.ConfigError, match=r"forward\.kind='rigid_body'.*'custom'"):
        rigid_body.make(config_lib.ForwardModelConfig(kind="rigid_body"), robot, task)


def _mujoco_opspace_output(robot, site, qpos, qvel, tau):
    """``[qacc, xdd]`` of MuJoCo C: ``qacc`` of ``mj_forward`` with the torques, ``xdd``
    the site's classical acceleration from MuJoCo's own ``cacc`` recursion
    (``mj_objectAcceleration``, :func:`sites.mujoco_site_acceleration`) at that ``qacc``."""
    qacc = _mujoco_qacc(robot, qpos, qvel, tau)
    return np.concatenate(
        [qacc, sites.mujoco_site_acceleration(robot.mj_model, site, qpos, qvel, qacc)]
    )


@pytest.mark.parametrize(
    ("name", "site"),
    [("two_link_arm", "tip"), pytest.param("iiwa14", "flange", marks=pytest.mark.slow)],
)
def test_opspace_zero_residual_predicts_mujoco_qacc_and_site_acceleration(name, site):
    """The op-space output ``[qacc, J qacc + Jdot qd]`` with a zero residual is MuJoCo C's,
    and its Jacobian in ``tau`` is that of MuJoCo C (central differences)."""
    robot = robots.load(name)
    task = tasks.make(robot, config_lib.TaskConfig(name="opspace", duration=0.1, site=site), 0.01)
    sid = task.site
    rng = np.random.default_rng(4)
    fm, params = _model(robot, task)
    norm = _normaliser(task, robot, rng)

    def both(s, t):
        y = _predict(fm, params, norm, s, t)
        return y, y

    predict = jax.jit(jax.jacfwd(both, argnums=1, has_aux=True))
    for qpos, qvel, tau in _random_states(robot, rng, 3):
        state = jnp.asarray(np.concatenate([qpos, qvel]), jnp.float32)
        expected = _mujoco_opspace_output(robot, sid, qpos, qvel, tau)
        got_jacobian, got = (np.asarray(x) for x in predict(state, jnp.asarray(tau, jnp.float32)))
        assert got.shape == (robot.nv + 3,)
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-5 * np.max(np.abs(expected)))
        eps = 1e-3 * robot.torque_limit
        columns = []
        for j in range(robot.action_dim):
            step = np.zeros(robot.action_dim)
            step[j] = eps[j]
            plus = _mujoco_opspace_output(robot, sid, qpos, qvel, tau + step)
            minus = _mujoco_opspace_output(robot, sid, qpos, qvel, tau - step)
            columns.append((plus - minus) / (2 * eps[j]))
        expected_jacobian = np.stack(columns, axis=1)
        np.testing.assert_allclose(
            got_jacobian, expected_jacobian, rtol=0, atol=2e-5 * np.max(np.abs(expected_jacobian))
        )


def test_protocol_line_names_the_forward_model_and_a_nominal_that_is_not_the_default():
    from cfm_jax.analysis import report

    base = config_lib.Config()
    assert report.protocol(base).endswith("; `forward.kind='mlp'`")
    exact = base.replace(forward=config_lib.ForwardModelConfig(kind="rigid_body"))
    assert report.protocol(exact).endswith("; `forward.kind='rigid_body'`")
    biased = base.replace(
        forward=config_lib.ForwardModelConfig(
            kind="rigid_body",
            options=rigid_body.RigidBodyOptions(nominal="two_link_arm", mass_scale=0.8),
        )
    )
    assert report.protocol(biased).endswith(
        "; `forward.kind='rigid_body'` (`forward.options.nominal='two_link_arm'`, "
        "`forward.options.mass_scale=0.8`)"
    )


def test_forward_config_fields_validated_and_round_trip():
    with pytest.raises(config_lib.ConfigError, match=r"forward\.kind='gru'"):
        config_lib.ForwardModelConfig(kind="gru")
    # The kind checks its own options, named as the user wrote them.
    with pytest.raises(config_lib.ConfigError, match=r"forward\.options\.mass_scale=0 "):
        config_lib.ForwardModelConfig(kind="rigid_body", options={"mass_scale": 0})
    with pytest.raises(config_lib.ConfigError, match=r"forward\.options\.nominal=''"):
        config_lib.ForwardModelConfig(kind="rigid_body", options={"nominal": ""})
    with pytest.raises(
        config_lib.ConfigError,
        match=r"forward\.options\.depth=3 .*'rigid_body', one of \['nominal', 'mass_scale'\]",
    ):
        config_lib.ForwardModelConfig(kind="rigid_body", options={"depth": 3})
    # The mlp takes no options: another kind's option is refused unless it is that kind's
    # default (a sweep over forward.kind carries the base kind's options; they say nothing).
    with pytest.raises(
        config_lib.ConfigError, match=r"forward\.options\.mass_scale=2\.0 .*'mlp' takes none"
    ):
        config_lib.ForwardModelConfig(options={"mass_scale": 2.0})
    plain = config_lib.ForwardModelConfig(options={"nominal": None, "mass_scale": 1.0})
    assert plain.options is None and plain == config_lib.ForwardModelConfig()
    with pytest.raises(config_lib.ConfigError, match=r"forward\.options=3 "):
        config_lib.ForwardModelConfig(kind="rigid_body", options=3)
    # A dict, the options object and None (the kind's defaults) give the same config.
    as_dict = config_lib.ForwardModelConfig(kind="rigid_body", options={"mass_scale": 0.8})
    as_object = config_lib.ForwardModelConfig(
        kind="rigid_body", options=rigid_body.RigidBodyOptions(mass_scale=0.8)
    )
    assert as_dict == as_object and as_dict.options.nominal is None
    assert config_lib.ForwardModelConfig(kind="rigid_body").options == rigid_body.RigidBodyOptions()
    cfg = config_lib.Config(
        forward=config_lib.ForwardModelConfig(
            kind="rigid_body", options={"nominal": "two_link_arm", "mass_scale": 0.8}
        )
    )
    assert config_lib.from_dict(config_lib.to_dict(cfg)) == cfg
    assert config_lib.to_dict(cfg)["forward"]["options"] == {
        "nominal": "two_link_arm",
        "mass_scale": 0.8,
    }
    assert config_lib.structure(cfg) != config_lib.structure(config_lib.Config())
    assert sorted(forward_models.REGISTRY) == sorted(config_lib.FORWARD_KINDS)


def test_config_json_written_before_options_reads_as_today():
    # config.json of runs before forward.options had the rigid_body kind's fields beside the
    # shared ones (the committed robustness records); they read as the same experiment.
    old = config_lib.to_dict(config_lib.Config())
    old["forward"].pop("options")
    mlp = {**old, "forward": {**old["forward"], "nominal": None, "nominal_mass_scale": 1.0}}
    assert config_lib.from_dict(mlp) == config_lib.Config()
    biased = {
        **old,
        "forward": {**old["forward"], "kind": "rigid_body", "nominal": "two_link_arm",
                    "nominal_mass_scale": 0.8},
    }  # fmt: skip
    assert config_lib.from_dict(biased).forward.options == rigid_body.RigidBodyOptions(
        "two_link_arm", 0.8
    )
    wrong = {**old, "forward": {**old["forward"], "nominal_mass_scale": 0.8}}  # mlp: refused
    with pytest.raises(config_lib.ConfigError, match=r"forward\.options\.mass_scale=0\.8"):
        config_lib.from_dict(wrong)


@pytest.mark.slow  # ~20 s (native), longer on mjx: compiles a whole iteration
@pytest.mark.parametrize("simulator", ["native", "mjx"])
def test_tiny_train_with_rigid_body_stores_mujocos_terms_with_the_data(simulator):
    base = tiny_config(iterations=1, seeds=1)
    config = dataclasses.replace(
        base,
        simulator=simulator,
        forward=dataclasses.replace(base.forward, kind="rigid_body"),
    )
    result = cfm_jax.train(config, progress=False)
    assert np.all(np.isfinite(result.metrics["prediction_error"]))
    data = jax.tree.map(lambda x: np.asarray(x[0]), result.state.data)
    size = int(data.size)
    assert size == data.capacity  # babbling + 1 iteration: every row filled
    robot = robots.load("two_link_arm")
    m = robot.mj_model
    d = mujoco.MjData(m)
    for row in (0, size // 2, size - 1):  # babbling rows and the iteration's
        d.qpos[:], d.qvel[:] = data.data.state[row, :2], data.data.state[row, 2:]
        mujoco.mj_forward(m, d)
        mass = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, mass)
        inverse = np.linalg.inv(mass)
        np.testing.assert_allclose(data.data.terms.gain[row], inverse, rtol=1e-4, atol=1e-4)
        drift = inverse @ (d.qfrc_passive - d.qfrc_bias)
        np.testing.assert_allclose(data.data.terms.drift[row], drift, rtol=1e-4, atol=1e-3)


def _rigid_body_config(base, **task):
    return dataclasses.replace(
        base,
        task=dataclasses.replace(base.task, **task),
        forward=dataclasses.replace(base.forward, kind="rigid_body"),
    )


@pytest.mark.slow  # ~55 s on 2 busy cores: compiles a whole iteration with the site terms
def test_tiny_opspace_train_with_rigid_body_has_finite_metrics_and_site_terms():
    config = _rigid_body_config(tiny_config(iterations=1, seeds=1), name="opspace", site="tip")
    result = cfm_jax.train(config, progress=False)
    assert len(result.metrics) > 0
    for column in ("tracking_mse", "prediction_error"):
        assert np.all(np.isfinite(result.metrics[column]))
    data = jax.tree.map(lambda x: np.asarray(x[0]), result.state.data)
    assert data.data.terms.gain.shape[1:] == (2 + 3, 2)  # [qacc, xdd] per unit torque
    robot = robots.load("two_link_arm")
    row = int(data.size) - 1
    qpos, qvel = data.data.state[row, :2], data.data.state[row, 2:]
    tau = np.array([0.3, -0.2]) * robot.torque_limit
    expected = _mujoco_opspace_output(robot, 0, qpos, qvel, tau)
    got = data.data.terms.gain[row] @ tau + data.data.terms.drift[row]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4 * np.max(np.abs(expected)))


@pytest.mark.slow  # ~110 s on 2 busy cores: two runs of 2 iterations
def test_rigid_body_resume_after_a_lost_last_checkpoint_is_bit_identical(tmp_path):
    """The terms are not in the checkpoint's data files (derived from the states): a run
    resumed from iteration 1 recomputes them and ends bit for bit as the whole run."""
    import shutil

    config = _rigid_body_config(tiny_config(iterations=2, seeds=1, checkpoint_keep=2))
    out = tmp_path / "full"
    full = cfm_jax.train(config, progress=False, out_dir=str(out))
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "checkpoints" / "2")
    assert (copy / "checkpoints" / "1").is_dir()  # it resumes from iteration 1
    resumed = cfm_jax.train(config, progress=False, resume=str(copy))
    pd.testing.assert_frame_equal(resumed.metrics, full.metrics, check_exact=True)
    for got, want in zip(
        jax.tree.leaves(resumed.state.data.data.terms),
        jax.tree.leaves(full.state.data.data.terms),
        strict=True,
    ):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
