"""Knowledge exchange: what a robot knows and how it asks, answers, checks and learns.

Agents (``agent``), their knowledge (``knowledge``), the wire messages (``messages``), the checks
on a received answer (``receiving``), signatures and trust (``signing``, ``trust``), memory
(``memory``), fleet events (``events``), the transfer log (``transferlog``), overhearing
(``overhearing``) and the interface every transport implements (``transport``). It uses the
language below it and knows no concrete network (``spec/protocol.md``).
"""
