"""``ktbt monitor``: a live view of a fleet in the browser, built from the fleet events peers
publish (``spec/protocol.md`` section 10), their liveliness tokens and their catalogs.

Needs the ``monitor`` extra (starlette, uvicorn): ``pip install 'ktbt[monitor]'``. Modules:
``fleet`` (the state, bounded), ``listen`` (zenoh), ``app`` (starlette: the page and its
server-sent events), ``command`` (the typer command); the page is ``static/``, plain JavaScript
and CSS. Names are imported from their modules: this package loads nothing, so the command
line starts without the extra.
"""

__all__: list[str] = []
