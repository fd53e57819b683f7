"""A fleet of real ``ktbt peer`` processes on one machine, every link through a fault layer
(``ktbt fleet run``), the properties checked over its record, and the study of how fast
knowledge spreads under which faults (``make soak``). docs/howto/fleet.md.

Modules, in the order data flows: ``plan`` (what to run: peers, links, addresses, the seeded
fault schedule), ``proxy`` (the user-space TCP proxy per link: delay, silent partition, hard cut,
heal), ``netns`` (a network namespace with an nftables loss rule), ``runner`` (processes,
schedule, observation, the record), ``check`` (the properties over a record), ``figure``,
``study`` and ``cli``. Names are imported from their modules: this package loads nothing.
"""

__all__: list[str] = []
