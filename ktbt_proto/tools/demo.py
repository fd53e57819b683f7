"""The demo robot and ``ktbt tour``.

The demo robot is the search-and-rescue robot of the example knowledge (``DEMO_CONTROL`` and
its vocabulary ``demo_registry``): what ``ktbt peer run`` and ``ktbt fleet run`` run when asked
for (``--demo``) or when given neither ``--vocabulary`` nor ``--control``, and what the tour's
two agents are.

``ktbt tour`` is a short tour of the language on the example trees, in one screen (about 40
lines). It runs the same code paths as ``ktbt fmt``, ``check`` and ``show``, so what a newcomer
sees is what the tools do, on the paper's own control tree.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from pydantic import Field

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.errors import StringBTError
from ktbt_proto.files import packaged
from ktbt_proto.formatter import format_tree
from ktbt_proto.registry import Registry
from ktbt_proto.render import render
from ktbt_proto.status import RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse
from ktbt_proto.tools.vocabulary import load_vocabulary
from ktbt_proto.validate import find_problems

Colour = Annotated[int, Field(ge=1, le=4)]
"""The demo's colours: 1 to 4. A received skill naming colour 7, -999 or "red" is refused."""

DEMO_CONTROL = """<sl>
    <sq>
        <c>(Carrying)
        <a>(DeliverToZone)
    <e>
    <k>(prior)<e>
    <k>(new)<e>
    <a>(RandomWalk)
<e>
"""
"""The demo robot's control tree: deliver what it carries, else what it knows, else walk."""


def demo_registry() -> Registry:
    """The search-and-rescue vocabulary of the example knowledge, with stand-in actions: each
    reads and writes only the blackboard (``pure``), so an idle demo robot may rest."""
    reg = Registry()
    reg.flags("Carrying")

    @reg.condition("TargetSeen", pure=True)
    def target_seen(bb: Blackboard, colour: Colour) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("PickTreasure", pure=True)
    def pick(bb: Blackboard) -> Status:
        bb["Carrying"] = True
        return SUCCESS

    @reg.action("AssignCollectionPoint", pure=True)
    def assign(bb: Blackboard, colour: Colour) -> Status:
        bb["zone"] = colour
        return SUCCESS

    @reg.action("DeliverToZone", pure=True)
    def deliver(bb: Blackboard) -> Status:
        bb["Carrying"] = False
        bb["delivered"] = bb.get("delivered", 0) + 1
        return SUCCESS

    @reg.action("RandomWalk", pure=True)
    def walk(bb: Blackboard) -> Status:
        return RUNNING

    return reg


_BROKEN = """<sl>
    <sq>
        <c>(_collisionDetectedF)
        <a>(CollisionAvoidance, speed=)
    <e>
<e>
"""

_UNKNOWN = "<sq><c>(TargetSeen, colour=3)<a>(PickTreasure)<a>(Teleport)<e>"

# Written flat, as the paper does: the conditions, then the actions (spec section 4).
_SKILL = "<sq><c>(TargetSeen, colour=2)<a>(PickTreasure)<a>(AssignCollectionPoint, colour=2)<e>"


def _section(title: str) -> None:
    typer.echo("")
    typer.secho(f"== {title}", bold=True)


def examples_folder() -> Path:
    """The examples shipped in the package."""
    return packaged("examples")


def run_demo(examples: Path) -> int:
    """The tour: each section one command and what it shows, in about 40 lines."""
    paper = examples / "paper_control.sbt"
    registry = examples / "sar_vocabulary.toml"
    for path in (paper, registry):
        if not path.is_file():
            typer.echo(f"error: --examples: {path} not found", err=True)
            return 1

    _section(f"ktbt fmt --compact: the paper's control tree ({paper.name}) on the wire")
    compact = format_tree(parse(paper.read_text(encoding="utf-8")), "compact")
    typer.echo(compact)
    rounds = 2000
    started = time.perf_counter()
    for _ in range(rounds):
        parse(compact)
    took = (time.perf_counter() - started) / rounds * 1e6
    typer.echo(f"({len(compact)} characters, one line; parsed in {took:.0f} µs here)")

    _section("ktbt fmt: the pretty form, one node per line (a skill to teach)")
    typer.echo(format_tree(parse(_SKILL)).rstrip())

    _section("ktbt check: every error has a code, a position and a caret")
    try:
        parse(_BROKEN)
    except StringBTError as err:
        typer.echo(f"broken.sbt:{err}")

    _section(f"ktbt check --vocabulary {registry.name}: knowledge a robot cannot run")
    typer.echo(_UNKNOWN)
    vocabulary = load_vocabulary(registry)
    for problem in find_problems(parse(_UNKNOWN), vocabulary):
        typer.echo(
            f"knowledge.sbt:{problem.line}:{problem.column}: {problem.code} {problem.message}"
        )
    _section("ktbt show: r2 meets a green target it knows nothing about")
    _transfer_showcase()
    typer.echo("")
    typer.echo("Next: ktbt fmt --help, ktbt peer --help; spec/stringbt.md, spec/protocol.md.")
    return 0


def _transfer_showcase() -> None:
    """Two agents on the in-memory network: r1 knows the green skill, r2 asks and learns it."""
    from ktbt_proto.exchange.agent import Agent, Timing
    from ktbt_proto.transport.memory import MemoryNetwork

    net = MemoryNetwork()
    knower = DEMO_CONTROL.replace("<k>(prior)<e>", f"<k>(prior){_SKILL}<e>")
    r1 = Agent("r1", knower, demo_registry(), net.join("r1"), timing=Timing(wait=20, cooldown=20))
    r2 = Agent("r2", DEMO_CONTROL, demo_registry(), net.join("r2"), timing=Timing(wait=20))
    r2.encounter(["TargetSeen(colour=2)"])
    r2.blackboard["target"] = 2
    for tick in range(1, 6):
        net.step()
        r1.tick()
        r2.tick()
        if "<c>(TargetSeen,colour=2)" in r2.metrics.learned:
            typer.echo(f"tick {tick}: r2 asked, r1 answered, r2 merged the skill while running:")
            break
    typer.echo(render(r2.control.tree).rstrip())
    r2.tick()
    typer.echo(f"next tick: r2 picks the target up and heads for zone {r2.blackboard.get('zone')}")
