"""experiments/robot_zoo.py: its summary of a run against a hand computation, and its
per-folder flags file (the study itself is not run here: minutes per robot)."""

from __future__ import annotations

import json
import os

import pytest
import robot_zoo


def test_summary_of_a_run_by_hand(tmp_path):
    # Two seeds, two targets, final iteration 1; joint's seed 1 target 1 diverged.
    rows = ["loss,seed,iteration,target,tracking_mse,diverged"]
    for loss, values in {"joint": [1.0, 3.0, 5.0, 99.0], "task": [0.1, 0.3, 0.2, 0.4]}.items():
        for seed in (0, 1):
            for target in (0, 1):
                rows.append(f"{loss},{seed},0,{target},50.0,0")
                v = values[2 * seed + target]
                rows.append(f"{loss},{seed},1,{target},{v},{int(v == 99.0)}")
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "baselines.csv").write_text(
        "baseline,target,tracking_mse\noracle,0,1e-4\noracle,1,3e-4\npd_only,0,2.0\npd_only,1,4.0\n"
    )
    s = robot_zoo.summarise(str(tmp_path))
    assert s["pd_only"] == 3.0 and s["oracle"] == pytest.approx(2e-4)
    # joint: seed 0 mean (1 + 3) / 2 = 2, seed 1 mean 5 (the diverged run left out).
    assert s["joint"]["stats"]["mean"] == pytest.approx(3.5)
    assert (s["joint"]["diverged"], s["joint"]["runs"], s["joint"]["below_pd"]) == (1, 4, 1)
    assert s["task"]["stats"]["mean"] == pytest.approx(0.25) and s["task"]["below_pd"] == 2
    text = robot_zoo.table([dict(robot="arm", wall_s=12.0, error=None, **s)], 2, "tests/x")
    assert "| arm | 3.5 [2, 5]; below PD 1/2; div. 1/4 | 0.25 [0.2, 0.3]; below PD 2/2 |" in text


def test_flags_file_is_read_and_checked(tmp_path):
    assert robot_zoo.flags_of(str(tmp_path)) == {}
    (tmp_path / "robots.json").write_text(json.dumps({"a.xml": ["--robot-torque-limit", "4"]}))
    assert robot_zoo.flags_of(str(tmp_path)) == {"a.xml": ["--robot-torque-limit", "4"]}
    (tmp_path / "robots.json").write_text(json.dumps({"a.xml": "--robot-torque-limit 4"}))
    with pytest.raises(SystemExit, match="'a.xml' must be a list of strings"):
        robot_zoo.flags_of(str(tmp_path))


def test_a_run_is_finished_when_every_loss_reached_its_last_iteration(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"loop": {"iterations": 2}}))
    rows = ["loss,seed,iteration,target,tracking_mse,diverged"]
    rows += [f"{loss},0,{i},0,1.0,0" for loss in robot_zoo.LOSSES[:3] for i in range(3)]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    assert not robot_zoo.finished(str(tmp_path))  # supervised missing
    rows += [f"supervised,0,{i},0,1.0,0" for i in range(2)]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    assert not robot_zoo.finished(str(tmp_path))  # supervised stopped at iteration 1
    rows.append("supervised,0,2,0,1.0,0")
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    assert robot_zoo.finished(str(tmp_path))
    assert not robot_zoo.finished(str(tmp_path / "nothing"))
    # Flags asking for more iterations than the run went: it is continued, not read.
    assert not robot_zoo.finished(str(tmp_path), ["--loop.iterations", "3"])
    assert robot_zoo.finished(str(tmp_path), ["--seeds", "3", "--loop.iterations", "2"])


def _finished_run(out, mse: float) -> None:
    out.mkdir(parents=True)
    (out / "config.json").write_text(json.dumps({"loop": {"iterations": 1}}))
    rows = ["loss,seed,iteration,target,tracking_mse,diverged"]
    rows += [f"{loss},0,{i},0,{mse},0" for loss in robot_zoo.LOSSES for i in range(2)]
    (out / "metrics.csv").write_text("\n".join(rows) + "\n")
    base = "baseline,target,tracking_mse\noracle,0,1e-6\npd_only,0,1.0\n"
    (out / "baselines.csv").write_text(base)


def test_only_one_robot_still_tables_every_finished_run(tmp_path):
    # Finished runs are read, never run again: --only a must keep b's row (alphabetically
    # after a) in the table it writes.
    robots = tmp_path / "robots"
    robots.mkdir()
    for stem in ("a", "b"):
        (robots / f"{stem}.xml").write_text("<mujoco/>")
        _finished_run(tmp_path / "out" / "seeds1" / stem, {"a": 0.5, "b": 0.25}[stem])
    page = tmp_path / "robots.md"
    robot_zoo.main(["--robots", str(robots), "--seeds", "1", "--out", str(tmp_path / "out"),
                    "--table", str(page), "--only", "a"])  # fmt: skip
    text = page.read_text()
    assert "| a | 0.5; below PD 1/1 |" in text and "| b | 0.25; below PD 1/1 |" in text


def test_another_folder_or_a_variant_must_name_its_page(tmp_path, capsys):
    # The default page is the arms' set's: a quadruped folder or a --tag run without --table
    # is refused before anything runs or is written (it once wrote over the arms' page).
    robots = tmp_path / "robots"
    robots.mkdir()
    (robots / "a.xml").write_text("<mujoco/>")
    arms_page = os.path.join(robot_zoo.ROOT, robot_zoo.ARMS_PAGE)
    before = os.path.getmtime(arms_page)
    for flags in (["--robots", str(robots)], ["--tag", "it30"]):
        with pytest.raises(SystemExit):
            robot_zoo.main([*flags, "--out", str(tmp_path / "out"), "--only", "zz"])
        assert "--table is required" in capsys.readouterr().err
    assert os.path.getmtime(arms_page) == before and not (tmp_path / "out").exists()


def test_a_variant_page_names_its_tag_and_flags_file(tmp_path):
    robots = tmp_path / "robots"
    robots.mkdir()
    (robots / "a.xml").write_text("<mujoco/>")
    flags = tmp_path / "more.json"
    flags.write_text(json.dumps({"a.xml": ["--loop.iterations", "1"]}))
    _finished_run(tmp_path / "out" / "seeds1_v" / "a", 0.5)
    page = tmp_path / "v.md"
    robot_zoo.main(["--robots", str(robots), "--seeds", "1", "--out", str(tmp_path / "out"),
                    "--table", str(page), "--tag", "v", "--flags-file", str(flags)])  # fmt: skip
    given = os.path.relpath(flags, robot_zoo.ROOT)
    assert f"Variant `v` (`--tag v --flags-file {given}`): added flags per file a.xml: " \
           "`--loop.iterations 1`" in page.read_text()  # fmt: skip


def test_a_refusal_and_a_robot_not_yet_run_stay_in_the_table(tmp_path):
    # c is refused by the library (no actuators); a later --only a run keeps c's reason
    # and says that d was not run, instead of dropping their rows.
    robots = tmp_path / "robots"
    robots.mkdir()
    for stem in ("a", "c", "d"):
        (robots / f"{stem}.xml").write_text("<mujoco/>")
    _finished_run(tmp_path / "out" / "seeds1" / "a", 0.5)
    page = tmp_path / "robots.md"
    common = ["--robots", str(robots), "--seeds", "1", "--out", str(tmp_path / "out"),
              "--table", str(page)]  # fmt: skip
    robot_zoo.main([*common, "--only", "c"])
    assert "| c | refused: " in page.read_text() and "has no actuators" in page.read_text()
    robot_zoo.main([*common, "--only", "a"])
    text = page.read_text()
    assert "| a | 0.5; below PD 1/1 |" in text
    assert "| c | refused: " in text and "has no actuators" in text
    assert "| d | not run yet |" in text


def test_the_code_column_names_both_commits_when_the_code_changed_during_a_run(
    tmp_path, monkeypatch
):
    versions = iter(["aaa1111", "bbb2222+changes", "ccc3333", "ccc3333"])
    monkeypatch.setattr(robot_zoo, "code_version", lambda root=None: next(versions))
    monkeypatch.setattr(robot_zoo, "machine", lambda: "a machine")

    def run(cmd, **kwargs):  # "trains": leaves a finished run in --out
        _finished_run(type(tmp_path)(cmd[cmd.index("--out") + 1]), 0.5)
        return robot_zoo.subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(robot_zoo.subprocess, "run", run)
    for name in ("first", "second"):
        row = robot_zoo.run_robot("arm.xml", str(tmp_path / name), 1, [])
        assert row["error"] is None
    assert (tmp_path / "first" / robot_zoo.CODE).read_text() == "aaa1111..bbb2222+changes\n"
    assert (tmp_path / "second" / robot_zoo.CODE).read_text() == "ccc3333\n"


def test_a_refused_robot_runs_again_afresh_and_a_started_one_resumes(tmp_path, monkeypatch):
    # A folder holding only an earlier refusal has no run to resume (the CLI refuses a
    # resume there, hiding the file's own reason); a folder with a started run resumes it.
    calls = []

    def run(cmd, **kwargs):
        if "train" in cmd:  # the zoo's other children (git, the machine's probe) aside
            calls.append(cmd)
        return robot_zoo.subprocess.CompletedProcess(cmd, 1, "", "cfm-jax: error: f): nope")

    monkeypatch.setattr(robot_zoo.subprocess, "run", run)
    out = tmp_path / "arm"
    robot_zoo.run_robot("arm.xml", str(out), 1, [])  # refused: writes the reason
    assert os.listdir(out) == [robot_zoo.REFUSED] and "--resume" not in calls[-1]
    robot_zoo.run_robot("arm.xml", str(out), 1, [])
    assert "--resume" not in calls[-1]
    (out / "config.json").write_text("{}")  # a run that started
    robot_zoo.run_robot("arm.xml", str(out), 1, [])
    assert "--resume" in calls[-1]


def test_code_version_is_the_commit_and_says_when_tracked_files_changed(tmp_path):
    import subprocess

    def git(*args):
        return subprocess.run(["git", "-C", str(tmp_path), *args], check=True,
                              capture_output=True, text=True).stdout.strip()  # fmt: skip

    assert robot_zoo.code_version(str(tmp_path)) == "unknown"  # not a checkout
    git("init", "-q")
    (tmp_path / "a.py").write_text("x = 1\n")
    git("add", "a.py")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "a")
    head = git("rev-parse", "--short", "HEAD")
    assert robot_zoo.code_version(str(tmp_path)) == head
    (tmp_path / "b.py").write_text("untracked\n")  # untracked files are not the code's
    assert robot_zoo.code_version(str(tmp_path)) == head
    (tmp_path / "a.py").write_text("x = 2\n")
    assert robot_zoo.code_version(str(tmp_path)) == head + "+changes"
    text = robot_zoo.table([dict(robot="arm", error="refused: no", wall_s=float("nan"))], 1, "t")
    assert text.rstrip().splitlines()[-1].count("|") == text.splitlines()[-2].count("|")


def test_the_machine_that_ran_a_robot_is_in_its_row(tmp_path):
    # The table mixes runs of several machines (a GPU's and a laptop's): each row names its
    # own, read from the run's folder; a run from before the record says so.
    import platform

    import jax

    robots = tmp_path / "robots"
    robots.mkdir()
    for stem in ("a", "b"):
        (robots / f"{stem}.xml").write_text("<mujoco/>")
        _finished_run(tmp_path / "out" / "seeds1" / stem, 0.5)
    (tmp_path / "out" / "seeds1" / "a" / robot_zoo.MACHINE).write_text("Some GPU, jax 9\n")
    page = tmp_path / "robots.md"
    robot_zoo.main(["--robots", str(robots), "--seeds", "1", "--out", str(tmp_path / "out"),
                    "--table", str(page), "--only", "a"])  # fmt: skip
    rows = {line.split(" | ")[0]: line for line in page.read_text().splitlines()}
    assert rows["| a"].endswith("| Some GPU, jax 9 |")
    assert rows["| b"].endswith("| not recorded |")
    # What a new run records: the device, the processor's model (/proc/cpuinfo's first
    # "model name", where there is one) and JAX that this interpreter's child sees.
    kind = jax.devices()[0].device_kind
    model = platform.processor() or platform.machine()
    if os.path.exists("/proc/cpuinfo"):
        names = [line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo")
                 if line.split(":")[0].strip() == "model name"]  # fmt: skip
        model = names[0] if names else model
        flags = next(line.split(":", 1)[1].split() for line in open("/proc/cpuinfo")
                     if line.startswith("flags"))  # fmt: skip
        model += " AVX-512" if "avx512f" in flags else " AVX2" if "avx2" in flags else ""
    want = (f"{kind} ({model}, {platform.machine()}, {os.cpu_count()} cores), "
            f"jax {jax.__version__}")  # fmt: skip
    assert robot_zoo.machine() == want


def _legged_run(out, forward: str = "mlp") -> None:
    # One seed, two references, final iteration 1. joint: fell on reference 1 only;
    # task: fell on both; PD-only fell on reference 0, the oracle never.
    out.mkdir(parents=True)
    config = {"loop": {"iterations": 1}, "forward": {"kind": forward}, "simulator": "native"}
    (out / "config.json").write_text(json.dumps(config))
    values = {"joint": ([0.2, 0.4], [0, 1]), "task": ([1.0, 3.0], [1, 1]),
              "distal": ([0.5, 0.5], [0, 0]), "supervised": ([4.0, 6.0], [0, 0])}  # fmt: skip
    rows = ["loss,seed,iteration,target,tracking_mse,diverged,fell"]
    for loss, (mse, fell) in values.items():
        for target in (0, 1):
            rows.append(f"{loss},0,0,{target},9.0,0,1")
            rows.append(f"{loss},0,1,{target},{mse[target]},0,{fell[target]}")
    (out / "metrics.csv").write_text("\n".join(rows) + "\n")
    (out / "baselines.csv").write_text(
        "baseline,target,tracking_mse,fell\noracle,0,1e-14,0\noracle,1,3e-14,0\n"
        "pd_only,0,1.5,1\npd_only,1,2.5,0\n"
    )


def test_a_legged_tasks_table_by_hand(tmp_path):
    # The walk's table: each loss's mean, its falls of the last iteration and its seeds
    # below PD-only (mean 2.0, fell 1/2), the oracle's, and the fallback in its row.
    _legged_run(tmp_path / "go2")
    s = robot_zoo.summarise(str(tmp_path / "go2"))
    assert s["pd_only"] == 2.0 and s["pd_only_fell"] == (1, 2) and s["oracle_fell"] == (0, 2)
    assert s["joint"]["stats"]["mean"] == pytest.approx(0.3) and s["joint"]["fell"] == 1
    assert s["task"]["fell"] == 2 and s["task"]["below_pd"] == 0
    defaults = {"forward.kind": "rigid_body", "simulator": "native"}
    changed = robot_zoo.changed_defaults(str(tmp_path / "go2"), defaults)
    assert changed == "forward.kind=mlp"
    row = dict(robot="go2", wall_s=61.0, error=None, changed=changed, code="abc", **s)
    text = robot_zoo.page({"walk": [row]}, 1, "tests/robots/quadrupeds", "", {"walk": defaults})
    assert "## walk" in text and "--tasks walk --seeds 1" in text
    assert (
        "| go2 | 0.3; fell 1/2; below PD 1/1 | 2; fell 2/2; below PD 0/1 | 0.5; fell 0/2; "
        "below PD 1/1 | 5; fell 0/2; below PD 0/1 | 2; fell 1/2 | 2e-14; fell 0/2 | "
        "forward.kind=mlp (MJX cannot build it) | 61 | abc |"
    ) in text
    # A robot that kept the defaults says none; a refusal keeps the row's width.
    assert robot_zoo.changed_defaults(str(tmp_path / "go2"), {"forward.kind": "mlp"}) == ""
    lines = robot_zoo.legged_rows([dict(robot="x", error="refused: no", wall_s=1.0)], 1)
    assert lines[-1].count("|") == lines[0].count("|")


def test_the_quadrupeds_flags_file_names_each_robots_actuators():
    folder = os.path.join(os.path.dirname(__file__), "robots", "quadrupeds")
    flags = robot_zoo.flags_of(folder)
    assert set(flags) == {f for f in os.listdir(folder) if f.endswith(".xml")}
    assert flags["go2.xml"] == ["--robot-actuators", "strict"]  # torque motors as published
    for servos in ("anymal_c.xml", "barkour_vb_mjx.xml"):
        assert flags[servos] == ["--robot-actuators", "torque"]


def test_the_fallback_rule_depends_only_on_whether_mjx_builds_the_robot():
    # The legged defaults' rigid-body model needs MJX: on a robot MJX cannot build, every
    # loss gets the native counterpart (one command, all four losses); otherwise nothing.
    walk = robot_zoo.defaults_of("walk")
    assert walk["forward.kind"] == "rigid_body"
    assert robot_zoo.fallback(walk, mjx_builds=False) == ["--forward.kind", "mlp"]
    assert robot_zoo.fallback(walk, mjx_builds=True) == []
    assert robot_zoo.fallback({"forward.kind": "rigid_body", "simulator": "mjx"}, False) == [
        "--forward.kind", "mlp", "--simulator", "native"]  # fmt: skip
    assert robot_zoo.fallback(robot_zoo.defaults_of("inverse_dynamics"), False) == []
    folder = os.path.join(os.path.dirname(__file__), "robots", "quadrupeds")
    flags = robot_zoo.flags_of(folder)
    go2 = robot_zoo.mjx_error(os.path.join(folder, "go2.xml"), flags["go2.xml"])
    assert "cannot build" in go2  # cylinder-box collisions: the Go2 gets mlp
    name = "barkour_vb_mjx.xml"
    assert robot_zoo.mjx_error(os.path.join(folder, name), flags[name]) is None  # keeps it


def test_a_legged_task_has_its_own_folder_and_section(tmp_path):
    # --tasks walk reads OUT/walk_seeds1/ROBOT (the arms' OUT/seeds1 untouched) and writes
    # the walk's section; a robot not run yet says so (nothing is run here).
    robots = tmp_path / "robots"
    robots.mkdir()
    for stem in ("a", "b"):
        (robots / f"{stem}.xml").write_text("<mujoco/>")
    _legged_run(tmp_path / "out" / "walk_seeds1" / "a", forward="rigid_body")
    page = tmp_path / "q.md"
    robot_zoo.main(["--robots", str(robots), "--seeds", "1", "--out", str(tmp_path / "out"),
                    "--table", str(page), "--tasks", "walk", "--only", "a"])  # fmt: skip
    text = page.read_text()
    assert "## walk" in text and "Defaults: forward.kind='rigid_body', simulator='native'." in text
    assert "| a | 0.3; fell 1/2; below PD 1/1 |" in text and "| none | nan |" in text
    assert "| b | not run yet |" in text and not (tmp_path / "out" / "seeds1").exists()
