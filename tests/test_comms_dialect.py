"""The private dialect: free id range, generation by mavgen into the cache, concurrent first loads."""
from __future__ import annotations

import dataclasses
import glob
import os
import subprocess
import sys
import textwrap
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from runtime.allocation.formation.messages import AGENT_MESSAGES, ROUND_MESSAGES
from runtime.comms import codec, dialect
from runtime.messages import FLEET_MESSAGES

ROOT = Path(__file__).resolve().parents[1]
OUR_BLOCK = range(44000, 44200)
FORMATION_XML = ROOT / "runtime" / "allocation" / "formation" / "formation.xml"


@pytest.fixture(scope="module", autouse=True)
def cache_dir(tmp_path_factory):
    old = os.environ.get("MRTA_CACHE_DIR")
    path = tmp_path_factory.getbasetemp() / "mrta-cache"
    os.environ["MRTA_CACHE_DIR"] = str(path)
    yield path
    if old is None:
        os.environ.pop("MRTA_CACHE_DIR", None)
    else:
        os.environ["MRTA_CACHE_DIR"] = old


def _ids(path: str) -> dict[int, str]:
    return {int(m.get("id")): m.get("name") for m in ET.parse(path).iter("message")}


def test_block_is_free_in_every_shipped_dialect():
    import pymavlink
    shipped = glob.glob(os.path.join(os.path.dirname(pymavlink.__file__), "**", "*.xml"), recursive=True)
    shipped = [p for p in shipped if Path(p).name not in ("mrta.xml", "formation.xml")]
    assert any(Path(p).name == "ardupilotmega.xml" for p in shipped)
    for path in shipped:
        clash = sorted(i for i in _ids(path) if i in OUR_BLOCK)
        assert not clash, f"{path} uses {clash}"


def test_one_message_per_class_each_in_its_block():
    """The runtime's own messages in mrta.xml (44100-44149), the formation family's beside its code (44000-44049),
    and the fleet dialect composed from the registry names both."""
    core = _ids(str(dialect.XML_PATH))
    assert sorted(core.values()) == sorted(codec.wire_name(c) for c in FLEET_MESSAGES)
    assert all(44100 <= i < 44150 for i in core)
    formation = _ids(str(FORMATION_XML))
    assert sorted(formation.values()) == sorted(codec.wire_name(c) for c in AGENT_MESSAGES + ROUND_MESSAGES)
    assert all(44000 <= i < 44050 for i in formation)
    top = dialect.fleet_xml().read_text()
    assert "<include>mrta.xml</include>" in top and "<include>formation.xml</include>" in top


def test_generated_module_matches_the_dataclasses(cache_dir):
    path = dialect.ensure()                            # honours MRTA_CACHE_DIR
    assert path.is_file() and path.is_relative_to(cache_dir)
    mod = dialect.load()
    assert Path(mod.__file__).read_bytes() == path.read_bytes()
    assert mod.WIRE_PROTOCOL_VERSION == "2.0"
    codec.check(mod)                                   # raises on any field-name mismatch
    for cls in AGENT_MESSAGES:
        wire = mod.mavlink_map[getattr(mod, f"MAVLINK_MSG_ID_{codec.wire_name(cls)}")]
        names = {f.name for f in dataclasses.fields(cls)} - {"sender", "dest"}
        assert set(wire.fieldnames) == names | {"target_system"}
    assert dialect.load() is mod                       # cached in-process


def test_cache_is_keyed_by_xml_contents(tmp_path):
    xml = tmp_path / "mrta.xml"
    text = dialect.XML_PATH.read_text()
    xml.write_text(text)
    k1 = dialect.cache_key(xml)
    assert k1 == dialect.cache_key(dialect.XML_PATH)
    xml.write_text(text.replace("East in the fleet frame.", "Easting in the fleet frame."))
    assert dialect.cache_key(xml) != k1
    path = dialect.ensure(xml, root=tmp_path / "cache")
    assert path.parent.name == f"mavlink-{dialect.cache_key(xml)}"
    assert not list((tmp_path / "cache").glob(".gen-*"))
    assert not (ROOT / "runtime" / "comms" / "mrta.py").exists()


def test_bad_dialect_is_reported_with_its_file(tmp_path):
    xml = tmp_path / "broken.xml"
    xml.write_text(dialect.XML_PATH.read_text().replace('name="task"', 'name="class"', 1))
    with pytest.raises(dialect.DialectError, match="broken.xml"):
        dialect.ensure(xml, root=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("mavlink-*"))


def test_concurrent_first_loads_in_separate_processes(tmp_path):
    cache, go = tmp_path / "cache", tmp_path / "go"
    script = textwrap.dedent(f"""
        import os, time
        while not os.path.exists({str(go)!r}):
            time.sleep(0.002)
        from runtime.comms import dialect
        mod = dialect.load(dialect.fleet_xml())       # generated into the cache (load() takes the shipped one)
        print(mod.__file__, mod.MAVLINK_MSG_ID_MRTA_BID)
    """)
    env = dict(os.environ, MRTA_CACHE_DIR=str(cache))
    procs = [subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(4)]
    time.sleep(0.3)                                    # let every interpreter reach the wait loop
    go.touch()
    outs = [p.communicate(timeout=60) for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, [e for _, e in outs]
    lines = {o.strip() for o, _ in outs}
    assert len(lines) == 1
    path, msgid = lines.pop().split()
    assert msgid == "44002" and Path(path).parent.parent == cache
    # no temp dirs left: the generated module and the composed top file of the fleet dialect
    assert sorted(p.name for p in cache.iterdir() if not p.name.startswith("fleet-")) == [Path(path).parent.name]
    assert len([p for p in cache.iterdir() if p.name.startswith("fleet-")]) == 1


def test_concurrent_ensure_in_threads(tmp_path):
    from concurrent.futures import ThreadPoolExecutor
    root = tmp_path / "cache"
    stdout = sys.stdout
    with ThreadPoolExecutor(4) as ex:
        paths = list(ex.map(lambda _: dialect.ensure(root=root), range(4)))
    assert len(set(paths)) == 1 and paths[0].is_file()
    assert sys.stdout is stdout                        # mavgen's chatter redirect was undone
    assert len([p for p in root.iterdir() if p.name.startswith("mavlink-")]) == 1
    assert len(list(root.iterdir())) == 2                # and the composed fleet top file


def test_includes_resolve_beside_the_dialect_then_in_pymavlink(tmp_path):
    (tmp_path / "extra.xml").write_text("""<?xml version="1.0"?>
<mavlink>
  <messages>
    <message id="44050" name="MRTA_EXTRA">
      <description>test</description>
      <field type="uint8_t" name="target_system">dest</field>
      <field type="float" name="value">value</field>
    </message>
  </messages>
</mavlink>
""")
    xml = tmp_path / "mrta.xml"
    xml.write_text(dialect.XML_PATH.read_text().replace(
        "<include>common.xml</include>", "<include>common.xml</include>\n  <include>extra.xml</include>"))
    names = [n for n, _ in dialect.sources(xml)]
    assert names[:3] == ["mrta.xml", "common.xml", "extra.xml"] and "minimal.xml" in names
    mod = dialect.load(xml)
    assert mod.MAVLINK_MSG_ID_MRTA_EXTRA == 44050 and mod.MAVLINK_MSG_ID_MRTA_TASK_RECORD == 44100
    xml.write_text(xml.read_text().replace("extra.xml", "missing.xml"))
    with pytest.raises(dialect.DialectError, match="missing.xml"):
        dialect.cache_key(xml)


def test_unwritable_cache_is_one_clear_error(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    with pytest.raises(dialect.DialectError, match="not-a-dir/cache: cannot write the MAVLink cache") as e:
        dialect.ensure(root=blocker / "cache")
    assert "\n" not in str(e.value)
