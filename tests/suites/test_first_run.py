"""A first run without surprises: every mistake a newcomer makes gets one clear line and the
right exit code, nothing is lost, and the commands agree with one another. Real processes,
real files, real zenoh peers on loopback."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pygame
import pytest

import ktbt_proto as kp
from ktbt_sim import viewer
from ktbt_sim.results import finished
from ktbt_sim.scenario import preset
from ktbt_sim.world import World
from tests.zenoh_helpers import endpoint, free_port, ktbt_run, serving, wait_until

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def ktbt(
    *args: str, cwd: Path = ROOT, env: dict[str, str] | None = None, stdin: bytes | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=300,
        input=None if stdin is None else stdin.decode(),
    )


def one_line(done: subprocess.CompletedProcess[str]) -> str:
    assert "Traceback" not in done.stderr and "─" not in done.stderr  # no typer box
    assert done.stderr.count("\n") == 1, done.stderr
    return done.stderr.strip()


# -- peers: what the user types and reads --------------------------------------------------


@pytest.mark.network
def test_ask_says_whether_nobody_was_reachable_or_nobody_knew() -> None:
    nobody = ktbt_run("peer", "ask", "--sequence", "TargetSeen(colour=2)", "--connect",
                      endpoint(free_port()), "--timeout", "1")  # fmt: skip
    assert (nobody.returncode, nobody.stdout) == (1, "")
    assert nobody.stderr == "no answer: no peer reachable within 1 s\n"
    port = free_port()
    with serving(port):
        unknown = ktbt_run("peer", "ask", "--sequence", "TargetSeen(colour=9)", "--connect",
                           endpoint(port), "--timeout", "3")  # fmt: skip
        assert (unknown.returncode, unknown.stdout) == (1, "")
        assert unknown.stderr == "no answer: 1 peer reachable, none knows TargetSeen(colour=9)\n"
        # What `peer list` prints is what `--sequence` takes.
        listed = ktbt_run("peer", "list", "--connect", endpoint(port), "--timeout", "5")
        assert listed.returncode == 0
        skills = [line.strip() for line in listed.stdout.splitlines()[1:]]
        assert skills == [f"TargetSeen(colour={c})" for c in (1, 2, 3, 4)]
        asked = ktbt_run("peer", "ask", "--sequence", skills[2], "--connect", endpoint(port))
        assert asked.returncode == 0 and "<a>(AssignCollectionPoint, colour=3)" in asked.stdout


@pytest.mark.network
@pytest.mark.parametrize(
    ("typed", "message", "caret"),
    [
        ("TargetSeen(colour=2", "SBT104 missing ) to close the arguments", 19),
        ("TargetSeen(colour=2), !", "SBT101", 22),
        ("", "SBT107 the sequence names no condition", 0),
    ],
)
def test_a_mistyped_sequence_is_shown_where_it_was_typed(
    typed: str, message: str, caret: int
) -> None:
    done = ktbt("peer", "ask", "--sequence", typed, "--connect", endpoint(free_port()))
    assert done.returncode == 2 and done.stdout == ""
    head, text, mark = done.stderr.splitlines()
    assert head.startswith(f"error: --sequence {typed!r}: {message}")
    assert (text, mark) == (f"    {typed}", " " * (4 + caret) + "^")


@pytest.mark.network
def test_serve_names_the_knowledge_file_it_cannot_use(tmp_path: Path) -> None:
    typo = tmp_path / "typo.sbt"
    typo.write_text("<k>(prior)\n    <sq><c>(A)<a>(B)\n<e>\n")
    done = ktbt("peer", "serve", "--knowledge", str(typo))
    assert done.returncode == 2
    assert done.stderr.startswith(f"{typo}:4:1: SBT104 ")
    missing = ktbt("peer", "serve", "--knowledge", str(tmp_path / "nope.sbt"))
    assert missing.returncode == 2
    assert one_line(missing) == (
        f"error: cannot read --knowledge {tmp_path / 'nope.sbt'}: No such file or directory"
    )
    binary = tmp_path / "binary.sbt"
    binary.write_bytes(b"\xff\xfe<k>(x)<e>")
    done = ktbt("peer", "serve", "--knowledge", str(binary))
    assert done.returncode == 2 and done.stderr.startswith(f"{binary}:1:1: SBT100 ")
    empty = tmp_path / "empty.sbt"
    empty.write_text("<k>(prior)<a>(X)<e>\n")
    done = ktbt("peer", "serve", "--knowledge", str(empty))
    assert done.returncode == 2 and "no knowledge items" in one_line(done)


# -- files: the right file is blamed, nothing is lost -----------------------------------------


@pytest.mark.network
def test_convert_blames_the_file_it_could_not_write(tmp_path: Path) -> None:
    target = tmp_path / "no" / "dir" / "x.xml"
    done = ktbt("convert", str(EXAMPLES / "sar_control.sbt"), str(target))
    assert done.returncode == 1
    assert one_line(done) == (
        f"error: cannot convert {EXAMPLES / 'sar_control.sbt'}: cannot write {target}: "
        "No such file or directory"
    )
    source = tmp_path / "nope.sbt"
    done = ktbt("convert", str(source), str(tmp_path / "x.xml"))
    assert f"cannot read {source}" in one_line(done)


@pytest.mark.network
def test_fmt_compact_never_drops_comments_from_a_file(tmp_path: Path) -> None:
    commented = tmp_path / "a.sbt"
    commented.write_text("# why\n<sq><c>(A)<a>(B)<e>\n")
    plain = tmp_path / "b.sbt"
    plain.write_text("<sq>\n    <c>(A)\n    <a>(B)\n<e>\n")
    done = ktbt("fmt", "--compact", str(tmp_path))
    assert done.returncode == 123
    assert commented.read_text() == "# why\n<sq><c>(A)<a>(B)<e>\n"  # untouched
    assert plain.read_text() == "<sq><c>(A)<a>(B)<e>\n"  # nothing to lose: rewritten
    assert f"error: cannot format {commented} compact in place: it has comments" in done.stderr
    printed = ktbt("fmt", "--compact", "-", stdin=commented.read_bytes())
    assert (printed.returncode, printed.stdout) == (0, "<sq><c>(A)<a>(B)<e>\n")


def test_a_trusted_action_that_returns_no_status_is_an_error() -> None:
    reg = kp.Registry()

    class Lazy:
        def __init__(self, bb: kp.Blackboard) -> None:
            pass

        def tick(self) -> kp.Status:
            return None  # type: ignore[return-value]

    reg.add_action("Lazy", Lazy)
    live = kp.LiveTree("<sl><a>(Lazy)<e>", reg)
    with pytest.raises(TypeError, match="returned None, not a Status"):
        live.tick()


# -- the simulator's commands ---------------------------------------------------------------


@pytest.mark.network
def test_sim_options_are_checked_in_one_line(tmp_path: Path) -> None:
    bad = ktbt("sim", "run", "ktbt", "--workers", "-3", "--out", str(tmp_path / "r"))
    assert bad.returncode == 2
    assert one_line(bad) == "error: --workers -3: use a number of processes, or 0 for all cores"
    assert not (tmp_path / "r").exists()
    movie = tmp_path / "x.mp4"
    bad = ktbt("sim", "view", "ktbt", "--record", str(movie))
    assert bad.returncode == 2 and "not .mp4" in one_line(bad)
    assert not movie.exists()
    bad = ktbt("sim", "view", "ktbt", "--frames", "-1")
    assert bad.returncode == 2 and one_line(bad).startswith("error: --frames -1:")


@pytest.mark.network
def test_a_scenario_file_reports_every_problem(tmp_path: Path) -> None:
    scenario = tmp_path / "my.toml"
    scenario.write_text('name = "mine"\ntrials = -1\nbogus = 1\n')
    done = ktbt("sim", "run", str(scenario))
    assert done.returncode == 2
    line = one_line(done)
    assert line.startswith(f"error: {scenario}: 2 problems: ")
    assert "trials:" in line and "bogus:" in line


@pytest.mark.network
def test_view_without_a_display_says_so_at_once() -> None:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")
    }
    done = ktbt("sim", "view", "ktbt", env=env)
    assert done.returncode == 2
    assert one_line(done) == (
        "error: no display to open a window on (DISPLAY and WAYLAND_DISPLAY are not set); "
        "record the run instead: --record run.gif"
    )


@pytest.mark.network
@pytest.mark.slow
def test_ctrl_c_stops_a_sweep_at_once_and_it_resumes(tmp_path: Path) -> None:
    out = tmp_path / "results"
    command = [sys.executable, "-m", "ktbt_proto", "sim", "run", "ktbt", "--trials", "8",
               "--iterations", "1500", "--workers", "2", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,  # its own process group, as a terminal's foreground job
        # with Ctrl-C's default action, even when the tests run as a background job (which
        # starts with SIGINT ignored, and Python keeps it ignored)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    try:
        folder = out / "ktbt"
        wait_until(lambda: folder.is_dir() and bool(finished(folder)), 120)
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does
        _, err = proc.communicate(timeout=60)  # a guard against a hang, not a timing check
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    saved = len(finished(folder))
    assert proc.returncode == 130
    assert 0 < saved < 8
    assert err.splitlines()[-1] == (
        f"interrupted: {saved} of 8 trials are saved in {out}; run the same command again "
        f"to resume with the {8 - saved} missing"
    )
    assert not list(folder.glob("*.tmp*"))  # no torn file left behind
    again = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    summary = again.stdout.splitlines()[-1]  # after the progress bar
    assert summary.startswith(f"ran {8 - saved} trials in ")
    assert f"({saved} {'was' if saved == 1 else 'were'} already there)" in summary
    assert finished(folder) == set(range(8))


# -- the viewer -----------------------------------------------------------------------------


def _close(a: tuple[int, int, int], b: tuple[int, int, int]) -> bool:
    return sum(abs(x - y) for x, y in zip(a, b, strict=True)) < 150


def test_status_lights_are_unlike_every_zone_and_target_colour() -> None:
    lights = (viewer.LIGHT_TEACHING, viewer.LIGHT_QUERYING, viewer.LIGHT_WALKING)
    for light in lights:
        assert not any(_close(light, zone) for zone in viewer.ZONE_RGB), light
        assert not _close(light, viewer.ROBOT)
    assert len(set(lights)) == 3


def test_the_legend_names_the_lights_and_robots_are_readable(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    world = World(preset("ktbt").with_(iterations=100), seed=1)
    for size in (400, 800):
        view = viewer.Viewer(world, size)
        assert view.robot_radius >= size // 100  # at least 8 pixels across in 800
        surface = view.draw()
        corner = surface.subsurface(pygame.Rect(0, 0, size // 2, size // 4))
        seen = {tuple(corner.get_at((x, y)))[:3] for x in range(0, size // 2) for y in
                range(0, size // 4)}  # fmt: skip
        for colour, _ in viewer.LEGEND:
            assert colour in seen  # each light has its swatch under the counters
    assert [text for _, text in viewer.LEGEND] == ["teaching", "asking", "searching"]


@pytest.mark.slow
def test_the_default_recording_is_long_enough_to_show_transfers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import inspect

    from ktbt_sim.cli import view_command

    defaults = inspect.signature(view_command).parameters
    span = (defaults["frames"].default - 1) * defaults["every"].default
    assert span >= 20_000  # the old default, 5,000 iterations, showed the first few queries only
    # Within this span of the paper's KT-BT run, knowledge spreads: robots learn colour after
    # colour (the counters' knowledge levels move).
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    world = World(preset("ktbt"), seed=0)
    start = int(world.known.sum())
    world.run(span)
    assert int(world.known.sum()) - start >= 10


def without_privileges() -> list[str]:
    """The prefix that runs a command unable to read what its owner may not: as root, root with
    every capability dropped (the same user, so the interpreter and the clone stay readable
    wherever they live, a private folder included; only the permission bits of a file count).
    Skips when root has no ``setpriv``."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: no file is unreadable")
    return ["setpriv", "--inh-caps=-all", "--ambient-caps=-all", "--bounding-set=-all"]


@pytest.mark.network
def test_unreadable_files_get_one_line_not_a_usage_box(tmp_path: Path) -> None:
    """Permission denied is the file's problem, said in one line, never typer's usage box."""
    folder = tmp_path / "locked"
    folder.mkdir()
    files = {
        "u.sbt": (EXAMPLES / "sar_control.sbt").read_text(),
        "u.toml": (EXAMPLES / "sar_vocabulary.toml").read_text(),
        "u.json": "{}",
    }
    for name, text in files.items():
        (folder / name).write_text(text)
        (folder / name).chmod(0)
    prefix = without_privileges()
    paper = str(EXAMPLES / "paper_control.sbt")
    for args, expected in [
        (
            ("check", "--vocabulary", "u.toml", paper),
            "error: --vocabulary: cannot read registry u.toml: ",
        ),
        (("peer", "serve", "--knowledge", "u.sbt"), "error: cannot read --knowledge u.sbt: "),
        (("peer", "ask", "--sequence", "A", "--config", "u.json"), "error: cannot read --config"),
        (("show", "u.sbt"), "error: cannot read u.sbt: "),
    ]:
        done = subprocess.run(
            [*prefix, sys.executable, "-m", "ktbt_proto", *args],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=120,
            env={**os.environ, "HOME": str(tmp_path)},
        )
        assert done.returncode in (1, 2)
        line = one_line(done)
        assert line.startswith(expected) and "Permission denied" in line, done.stderr


@pytest.mark.network
def test_fmt_rewrites_in_place_in_a_folder_it_cannot_create_files_in(tmp_path: Path) -> None:
    """A user may own a file in a folder they cannot write: ``fmt`` rewrites it in place."""
    folder = tmp_path / "shared"
    folder.mkdir()
    tree = folder / "t.sbt"
    tree.write_text("<sl><a>(A)   <a>(B)<e>")
    folder.chmod(0o555)
    try:
        done = subprocess.run(
            [*without_privileges(), sys.executable, "-m", "ktbt_proto", "fmt", "t.sbt"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        folder.chmod(0o755)
    assert done.returncode == 0, done.stderr
    assert tree.read_text() == "<sl>\n    <a>(A)\n    <a>(B)\n<e>\n"
    assert [p.name for p in folder.iterdir()] == ["t.sbt"]


# -- the library's mistakes: one line each, never zenoh's Rust or a Python attribute error ------


def test_an_endpoint_without_its_protocol_is_refused_when_the_settings_are_made() -> None:
    """Zenoh said ``Json5Err`` with Rust source paths; the settings refuse it, saying what to
    write, and ``--connect`` says the same in one line (exit 2)."""
    from ktbt_proto.transport.zenoh import EndpointError, ZenohSettings

    with pytest.raises(EndpointError) as info:
        ZenohSettings(connect=["127.0.0.1:7447"])
    assert str(info.value) == "connect: 127.0.0.1:7447 names no protocol: write tcp/127.0.0.1:7447"
    assert isinstance(info.value, ValueError) and info.value.endpoint == "127.0.0.1:7447"
    done = ktbt("peer", "ask", "--sequence", "TargetSeen(colour=2)", "--connect", "127.0.0.1:7447")
    assert (done.returncode, done.stdout) == (2, "")
    expected = "error: --connect: 127.0.0.1:7447 names no protocol: write tcp/127.0.0.1:7447"
    assert one_line(done) == expected


@pytest.mark.network
def test_a_port_in_use_names_the_endpoint_in_one_line() -> None:
    """A second listener on the same endpoint: zenoh's ``ZError`` with Rust paths becomes one
    line naming the endpoint, from the library and from ``ktbt peer serve``."""
    from ktbt_proto.transport.zenoh import SessionError, ZenohSettings, ZenohTransport

    port = free_port()
    taken = (
        f"cannot listen on {endpoint(port)}: address in use (another peer or program listens there)"
    )
    with ZenohTransport("first", ZenohSettings(listen=[endpoint(port)])):
        with pytest.raises(SessionError) as info:
            ZenohTransport("second", ZenohSettings(listen=[endpoint(port)]))
        assert str(info.value) == taken
        knowledge = str(EXAMPLES / "knowledge" / "colours.sbt")
        done = ktbt("peer", "serve", "--knowledge", knowledge, "--listen", endpoint(port))
        assert done.returncode == 2 and done.stdout == ""
        assert one_line(done) == f"error: {taken}"


def test_a_py_trees_tree_given_the_wrong_way_is_one_line() -> None:
    """``Agent(name, <BehaviourTree>)`` gave ``AttributeError: ... 'pos'`` and
    ``py_trees_control(root)`` ``AttributeError: ... 'pre_tick_handlers'``: each is one line
    now, saying what to pass."""
    import py_trees

    from ktbt_proto.interop.pytrees_control import py_trees_control

    root = py_trees.composites.Selector("Root", memory=False, children=[
        py_trees.composites.Selector("k:new", memory=False),
        py_trees.behaviours.Running("Wander"),
    ])  # fmt: skip
    bt = py_trees.trees.BehaviourTree(root)
    net = kp.MemoryNetwork()
    with pytest.raises(TypeError) as built:
        kp.Agent("r", bt, kp.Registry(), net.join("r"))  # type: ignore[arg-type]
    assert str(built.value) == (
        "Agent cannot run a BehaviourTree as its control tree: pass "
        "py_trees_control(tree, behaviours={...}) from ktbt_proto"
    )
    with pytest.raises(TypeError) as rooted:
        py_trees_control(root)  # type: ignore[arg-type]
    assert str(rooted.value) == (
        "a py_trees control tree is a py_trees.trees.BehaviourTree, not the behaviour 'Root': "
        "pass py_trees.trees.BehaviourTree(root)"
    )
    for error in (built.value, rooted.value):
        assert "\n" not in str(error)
    agent = kp.Agent("r2", py_trees_control(bt), kp.Registry(), net.join("r2"))
    assert agent.tick() is kp.RUNNING  # given the right way, it runs
