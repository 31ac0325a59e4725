"""The operator process: its composition root (``main.py``: settings -> adapters -> the
dispatcher -> kopf), the thin kopf handlers (``handlers/``), the dispatcher that routes events
to the controllers and runs their loops (``dispatch.py``) and the per-fleet queue
(``queue.py``)."""
