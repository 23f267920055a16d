"""`mrta sitl run`'s options, checked before the world is built: each wrong one is one InputError line naming it.

Numbers that override the fleet config (``--speedup``, ``--timeout``, ``--seed``, ``--peer-loss``, ``--loss-burst``)
take the fleet config's own ranges; ``--instance`` must leave every port of the fleet in 1..65535; the run folder,
the manifest and the JSON result must be writable now, not only when the run ends; ``--key`` must be a key file,
and asks for a signed fleet (not with ``--no-signing``); so does ``--unsigned-gcs``, each a network in CIDR form.
"""
from __future__ import annotations

import dataclasses

from runtime import argcheck
from runtime.errors import InputError
from sitl import fleet_config as FC
from sitl.ports import check_instance

MAX_INSTANCE = 400


def fleet_range(name: str) -> tuple[float | None, float | None]:
    """The ``[lo, hi]`` range of FleetConfig field ``name``."""
    meta = next(f.metadata for f in dataclasses.fields(FC.FleetConfig) if f.name == name)
    return meta.get("lo"), meta.get("hi")


def check(args) -> None:
    """InputError naming the option unless ``args`` (parsed `mrta sitl run` options) can start a run."""
    for name in ("speedup", "timeout", "seed", "peer_loss", "loss_burst"):
        lo, hi = fleet_range(name)
        argcheck.number(getattr(args, name), "--" + name.replace("_", "-"), lo, hi)
    argcheck.number(args.instance, "--instance", 0, MAX_INSTANCE)
    argcheck.output_dir(args.run_dir, "--run-dir")
    argcheck.output_file(args.manifest, "--manifest", make_parents=True)
    argcheck.output_file(args.json, "--json")
    if args.key is not None:
        if not args.signing:
            raise InputError("--key: expected a signed fleet, got --no-signing as well")
        from runtime.comms.link import load_key
        load_key(args.key, "--key")
    from runtime.comms.networks import EXPECTED, parse_network
    for net in args.unsigned_gcs or ():
        if not args.signing:
            raise InputError("--unsigned-gcs: expected a signed fleet, got --no-signing as well (every frame is "
                             "taken unsigned then)")
        try:
            parse_network(net)
        except ValueError as exc:
            raise InputError(f"--unsigned-gcs: expected {EXPECTED}, got {net!r} ({exc})") from None
    if args.instance:
        check_instance(FC.load_fleet(args.fleet), args.instance)
    segments = getattr(args, "segments", 1)
    if segments != 1 and getattr(args, "transport", "udp") != "zenoh":
        raise InputError(f"--segments: expected with --transport zenoh (UDP has no routers), got {segments}")
    argcheck.number(segments, "--segments", 1, len(FC.load_fleet(args.fleet).robots))
    if getattr(args, "transport", "udp") == "zenoh":
        from runtime.comms.zenoh_transport import load_zenoh
        load_zenoh()                  # one line naming the extra when it is missing
