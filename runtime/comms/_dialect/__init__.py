"""The fleet's MAVLink bindings, generated ahead of time by ``python -m runtime.comms.dialect --ship`` from the
dialect XML (``KEY``: the hash of that XML).  Do not edit ``mrta.py``; see :mod:`runtime.comms.dialect`."""
