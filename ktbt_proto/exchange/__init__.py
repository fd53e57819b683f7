"""Knowledge exchange: what a robot knows and how it asks, answers, checks and learns.

Agents: one core (``core``: the accept pipeline, knowledge, memory, overhearing) with its
security settings (``security``), driven by the teach and learn trees (``agent``) or by the
application (``application``), and the fleet member's loop every host runs (``member``); the
answers they give (``answers``); their knowledge
(``knowledge``), the wire messages (``messages``), the checks on a received answer
(``receiving``), signatures and trust (``signing``, ``trust``), memory (``memory``), fleet
events (``events``), the transfer log (``transferlog``), overhearing (``overhearing``) and the
interface every transport implements (``transport``). It uses the language below it and knows
no concrete network (``spec/protocol.md``).

Names are imported from their modules; this package re-exports none, so that importing one
module loads only what that module needs. ``import ktbt_proto as kp`` gives the ones a robot
builder uses (``kp.Agent``, ``kp.Security``, ``kp.FleetMember``...).
"""

__all__: list[str] = []
