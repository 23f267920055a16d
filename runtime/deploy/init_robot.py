"""`mrta init-robot DIR --base create2|pioneer|can`: an example ``/etc/mrta`` for one robot, and the shipped systemd
unit and udev rules (`mrta init-robot --print unit|udev`).

DIR gets three files, none of which is ever overwritten:

* ``robot.yaml``: the shipped example config of the base (``runtime/examples/robots``) made for a robot: its id and
  name, the serial ports by the names the udev rules give (``/dev/mrta-create2``, ``/dev/mrta-pioneer``,
  ``/dev/mrta-gps``; CAN on ``can0``), MAVLink on every interface (``0.0.0.0:14601``), the peers and ground station
  given, and the fleet key below.  Built and checked as ``mrta daemon --check`` does before anything is written.
* ``fleet.key``: a new fleet signing key made as ``mrta key`` makes it, or ``--key FILE`` copied (every robot of a
  fleet and its ground station share one key: make it on the first robot, copy it to the others).
* ``README.md``: the layout, and the commands that install the unit and the rules and start the daemon.

The unit (``mrta-daemon@.service``) and the rules (``99-mrta-serial.rules``) ship beside this module; ``--print``
writes one to stdout, the unit with ``ExecStart`` pointing at the ``mrta`` running it.  docs/deploy.md walks a
Raspberry Pi through all of it.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from runtime.errors import InputError

HERE = Path(__file__).resolve().parent
UNIT = HERE / "mrta-daemon@.service"
RULES = HERE / "99-mrta-serial.rules"
EXAMPLES = HERE.parent / "examples" / "robots"
UNIT_MRTA = "/opt/mrta/bin/mrta"           # where the shipped unit expects the robot's venv

GPS_PORT = "/dev/mrta-gps"
# --base -> (example config, what changes for a robot); serial names are the udev rules' SYMLINKs
BASES = {
    "create2": ("create2.yaml", {"base": {"port": "/dev/mrta-create2"}}),
    "pioneer": ("pioneer3dx.yaml", {"base": {"port": "/dev/mrta-pioneer"}}),
    "can": ("candiff.yaml", {"base": {"interface": "socketcan", "channel": "can0"}}),
}
LISTEN = "0.0.0.0:14601"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("init-robot", help="write an example /etc/mrta for one robot (config, fleet key, README)",
                       description="Write DIR/robot.yaml (the example config of --base with the udev names of its "
                                   "serial ports), DIR/fleet.key (new, or --key copied) and DIR/README.md; never "
                                   "overwrites.  --print unit|udev writes the shipped systemd unit or udev rules to "
                                   "stdout instead.")
    p.add_argument("dir", nargs="?", metavar="DIR", help="where to write (e.g. /etc/mrta; made if missing)")
    p.add_argument("--base", choices=list(BASES), help="the robot's base: create2 (iRobot Create 2, OI), pioneer "
                   "(Pioneer 3-DX, ARCOS), can (two CiA 402 drives on SocketCAN can0)")
    p.add_argument("--id", type=int, default=1, help="robot.id, 1..250, unique in the fleet (default 1)")
    p.add_argument("--name", default=None, help="robot.name (default: the base's name and the id)")
    p.add_argument("--peer", action="append", default=[], metavar="ID=HOST:PORT",
                   help="another robot of the fleet (repeat for each)")
    p.add_argument("--gcs", default=None, metavar="HOST:PORT",
                   help="a ground station to send telemetry to; without it the robot answers whichever ground "
                        "station heartbeats to it")
    p.add_argument("--key", default=None, metavar="FILE", help="the fleet's signing key to copy (default: a new one)")
    p.add_argument("--print", dest="show", choices=("unit", "udev"), default=None,
                   help="print the systemd unit (ExecStart: this mrta) or the udev rules, write nothing")
    p.set_defaults(func=_main)


def unit_text(mrta: str | None = None) -> str:
    """The shipped unit with ``ExecStart`` and ``ExecStopPost`` running ``mrta`` (default: the
    ``mrta`` script beside this Python, else the shipped /opt/mrta path)."""
    if mrta is None:
        here = Path(sys.executable).parent / "mrta"
        mrta = str(here) if here.is_file() else UNIT_MRTA
    return UNIT.read_text().replace(UNIT_MRTA, mrta)


def robot_config(base: str, robot_id: int, name: str | None, peers: list[str], gcs: str | None,
                 key_path: Path, config_path: Path, check_key: str | None = None) -> dict:
    """The plain data of ``robot.yaml`` for ``base``, checked as ``mrta daemon --check`` checks a config (ConfigError
    naming ``config_path`` and the key otherwise); the signing key is checked at ``check_key`` (None: not yet)."""
    from runtime.config import RobotConfig, deep_merge, from_dict, validate_robot
    from runtime.config.build import _read_yaml

    example, changes = BASES[base]
    data = deep_merge(_read_yaml(EXAMPLES / example), changes)
    data = deep_merge(data, {
        "robot": {"id": robot_id, "name": name or f"{base}-{robot_id}"},
        "gps": {"port": GPS_PORT},
        "comms": {"listen": LISTEN, "peers": [_peer(p) for p in peers], "gcs": gcs,
                  "signing_key": str(key_path)},
    })
    validate_robot(from_dict(RobotConfig, deep_merge(data, {"comms": {"signing_key": check_key}}), str(config_path)))
    return data


def _peer(text: str) -> dict:
    rid, sep, address = text.partition("=")
    rid = rid.strip()
    if not sep or not (rid.isascii() and rid.isdigit()):
        raise InputError(f"--peer: expected ID=HOST:PORT, got {text!r}")
    return {"id": int(rid), "address": address}


def init_robot(where: str | Path, base: str, robot_id: int = 1, name: str | None = None,
               peers: list[str] = (), gcs: str | None = None, key: str | None = None) -> list[Path]:
    """Write DIR/robot.yaml, DIR/fleet.key, DIR/README.md (InputError, nothing written, if any is there or the
    config would not load); the paths written."""
    import yaml

    from runtime.comms.link import load_key, new_key, write_key
    from runtime.config import validate_robot
    from runtime.config.robot import load_robot

    where = Path(where).absolute()
    config, key_path, readme = where / "robot.yaml", where / "fleet.key", where / "README.md"
    for path in (config, key_path, readme):
        if path.exists():
            raise InputError(f"{path}: a file is already there (mrta init-robot never overwrites)")
    fleet_key = load_key(key) if key is not None else None
    data = robot_config(base, robot_id, name, list(peers), gcs, key_path, config, key)
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{where}: cannot make the folder ({exc.strerror})") from None
    if fleet_key is None:
        new_key(key_path)
    else:
        write_key(key_path, fleet_key)
    example = BASES[base][0]
    for path, text in ((config, f"# {base} robot {robot_id}, written by mrta init-robot from the example "
                                f"runtime/examples/robots/{example}\n# (its comments say what each key does); "
                                "docs/deploy.md\n" + yaml.safe_dump(data, sort_keys=False)),
                       (readme, README.format(dir=where, base=base, id=robot_id, unit=UNIT.name, rules=RULES.name,
                                              port=BASES[base][1]["base"].get("port", "can0 (SocketCAN)")))):
        try:
            with open(path, "x") as fh:          # never over a file that appeared since the check above
                fh.write(text)
        except OSError as exc:
            raise InputError(f"{path}: cannot write it ({exc.strerror})") from None
    validate_robot(load_robot(config))         # the files as written load as they were checked
    return [config, key_path, readme]


def _main(args) -> int:
    if args.show == "unit":
        sys.stdout.write(unit_text())
        return 0
    if args.show == "udev":
        sys.stdout.write(RULES.read_text())
        return 0
    if args.dir is None or args.base is None:
        raise InputError("init-robot: expected DIR and --base create2|pioneer|can (or --print unit|udev)")
    written = init_robot(args.dir, args.base, args.id, args.name, args.peer, args.gcs, args.key)
    for path in written:
        print(path)
    print(f"next: {written[-1]} (install the unit and the udev rules, then systemctl enable --now "
          f"mrta-daemon@robot)")
    return 0


README = """\
# {dir}: one robot of an mrta fleet

Written by `mrta init-robot {dir} --base {base} --id {id}`.  docs/deploy.md in the mrta-runtime repository
walks a Raspberry Pi from a fresh OS to a daemon a ground station sees; this is the short version.

| file | what |
| --- | --- |
| `robot.yaml` | the robot config: `mrta daemon robot.yaml` runs it; the base on `{port}`, the GPS on `/dev/mrta-gps`, MAVLink on UDP port 14601 of every interface |
| `fleet.key` | the fleet's MAVLink 2 signing key (mode 0600): the same file on every robot and on the ground station |
| `README.md` | this file |

Every robot of a fleet has its own `robot.id` and lists the others as `comms.peers`; they all share
`fleet.key` (`mrta init-robot DIR --base ... --id 2 --key fleet.key` on the next robot) and the `datum`, the
latitude, longitude and altitude of the fleet frame's origin: set it to your site's on every robot.

## Install the service (as root)

```
useradd --system --no-create-home --home-dir /nonexistent --shell /usr/sbin/nologin --groups dialout mrta
chown mrta:mrta {dir}/fleet.key
mrta init-robot --print unit > /etc/systemd/system/{unit}
mrta init-robot --print udev > /etc/udev/rules.d/{rules}
udevadm control --reload && udevadm trigger --subsystem-match=tty
mrta daemon {dir}/robot.yaml --check
systemctl daemon-reload && systemctl enable --now mrta-daemon@robot
journalctl -u mrta-daemon@robot -f
```

The unit runs `mrta daemon {dir}/robot.yaml` as the user `mrta` (no home), restarts it after a crash or a lost
device (not after a bad config: exit 2), and `systemctl stop` sends SIGTERM, on which the daemon stops the base
and exits.  Its status snapshot is `/var/lib/mrta/robot.json`.

## From a ground station

```
mrta mission status ROBOT_IP:14601 --key fleet.key
```
"""
