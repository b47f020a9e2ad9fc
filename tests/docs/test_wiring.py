"""The docs' Raspberry Pi wiring is the example config's, and is given once.

- docs/raspberry-pi.md holds the table tests/docs/wiring.py generates from
  docs/examples/raspberry-pi.toml through the daemon's own loader, unchanged;
- the generator reads what the file says (checked against the TOML read plainly) and
  refuses a wiring the header cannot have;
- the SPI0 overlay the table names compiles (dtc) and gives the chip selects the table says;
- no other page holds a wiring table (a table with a GPIO, BCM or header-pin column), and
  the pages that show wiring point to the one table, whose anchor exists;
- no page (README.md, docs/*.md, the example's comments) names a GPIO for a role that the
  example gives another GPIO: in a TOML snippet (by motor name, pin number, bridge key) and
  in prose ("STEP GPIO17", "GPIO8 (CE0)", "end stop on GPIO26", "pin 0 on GPIO4").
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

from motorctl.daemon.config import parse_config
from motorctl.hal.backends.gpiod.wiring import LineRef
from tests.docs import wiring as w
from tests.support import REPO

PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
#: the pages that show wiring: each points to the table (raspberry-pi.md holds it)
POINTING = {
    "README.md": "docs/" + w.ANCHOR,
    "docs/hardware.md": w.ANCHOR,
    "docs/tmc.md": w.ANCHOR,
    "docs/dspin.md": w.ANCHOR,
}


def _rel(path: Path) -> str:
    return str(path.relative_to(REPO))


def outside_table(text: str) -> str:
    """A page without its generated wiring (which is checked against the generator)."""
    if w.BEGIN not in text:
        return text
    head, rest = text.split(w.BEGIN, 1)
    return head + rest.split(w.END, 1)[1]


# --- the table is the example's -------------------------------------------------------------


def test_the_page_holds_the_generated_table() -> None:
    page = w.PAGE.read_text(encoding="utf-8")
    assert w.block(page) == w.render(), (
        "docs/raspberry-pi.md's wiring table is not the example's: "
        "run python -m tests.docs.wiring --write"
    )
    assert page.index(w.SECTION) < page.index(w.BEGIN), "the table moved out of its section"


def plain_roles(text: str) -> dict[str, str]:
    """role -> line as the example's TOML writes it, read without the daemon's loader."""
    doc = tomllib.loads(text)
    roles: dict[str, str] = {}
    for i, m in enumerate(doc["motors"]):
        who = f"motor {i} ({m['name']})"
        g = m.get("gpiod", {})
        for key, role in (("step", "STEP"), ("dir", "DIR"), ("enable", "EN")):
            if key in g:
                roles[f"{who} {role}"] = g[key]
        for which in ("min", "max"):
            if f"endstop_{which}" in g:
                roles[f"{who} end stop {which}"] = g[f"endstop_{which}"]
        if "tmc" in m:
            bus, cs = re.fullmatch(r"/dev/spidev(\d)\.(\d)", m["tmc"]["spi"]).groups()  # type: ignore[union-attr]
            roles[f"{who} chip select, SPI{bus} CE{cs}"] = m["tmc"]["spi"]
    for key in ("in1", "in2", "en"):
        if key in doc["gpiod"].get("dc", {}):
            roles[f"DC motor {key.upper()}"] = doc["gpiod"]["dc"][key]
    for p in doc["pins"]:
        roles[f"pin {p['number']}"] = p["gpiod"]["line"]
    return roles


def test_the_table_has_every_line_and_chip_select_of_the_example() -> None:
    table = w.wiring().roles()
    plain = plain_roles(w.EXAMPLE.read_text(encoding="utf-8"))
    assert len(plain) == 23  # 3 x (STEP, DIR, end stop, chip select), the bridge's 3, 8 pins
    for role, line in plain.items():
        if line.startswith("/dev/spidev"):
            bus, cs = map(int, line.removeprefix("/dev/spidev").split("."))
            assert table[role] == w.spi_buses()[bus].chip_selects[cs], role
        else:
            assert table[role] == w.gpio_of(LineRef.parse(line)), role
    # and nothing else of the config: the rest are the board's (UART, SPI pins) or unwired
    board = {r for r in table if r.startswith(("host UART", "SPI0 "))}
    unwired = {r for r, g in table.items() if g is None}
    assert set(table) == set(plain) | board | unwired
    assert unwired == {f"motor {i} ({n}) EN" for i, n in enumerate("xyz")}


def changed(old: str, new: str) -> str:
    text = w.EXAMPLE.read_text(encoding="utf-8")
    assert text.count(old) == 1, old
    return text.replace(old, new)


def test_an_example_wired_otherwise_is_another_table() -> None:
    """Swapping x's end stop and pin 0's line: a table the page does not hold."""
    text = changed('endstop_min = "GPIO26"', 'endstop_min = "GPIO4"')
    text = text.replace('gpiod = { line = "GPIO4" }', 'gpiod = { line = "GPIO26" }')
    other = w.wiring(parse_config(text, "swapped.toml"))
    assert other.roles()["motor 0 (x) end stop min"] == 4
    assert w.render(other) != w.block(w.PAGE.read_text(encoding="utf-8"))


@pytest.mark.parametrize(
    ("old", "new", "problem"),
    [
        ('gpiod = { line = "GPIO4" }', 'gpiod = { line = "GPIO8" }', "GPIO8 is both"),
        ('gpiod = { line = "GPIO4" }', 'gpiod = { line = "GPIO14" }', "GPIO14 is both"),
        ('gpiod = { line = "GPIO4" }', 'gpiod = { line = "GPIO30" }', "not a line of the"),
        ('spi = "/dev/spidev0.2"', 'spi = "/dev/spidev0.3"', "no overlay gives SPI0 CE3"),
    ],
    ids=["a chip select", "the UART", "off the header", "a fourth chip select"],
)
def test_a_wiring_the_header_cannot_have_is_refused(old: str, new: str, problem: str) -> None:
    config = parse_config(changed(old, new), "bad.toml")  # the daemon's loader takes it
    with pytest.raises(w.WiringError, match=problem):
        w.wiring(config)


def test_the_boot_configuration_follows_the_chip_selects() -> None:
    full = w.wiring()
    assert full.boot == ("enable_uart=1", f"dtoverlay={w.OVERLAY_NAME}")
    z_chip = r'  \[motors\.tmc\][^\n]*\n  driver = "tmc5160"\n  spi = "/dev/spidev0\.2"\n'
    text, n = re.subn(
        z_chip + r"(  \w+ = [^\n]*\n)*",
        "",
        w.EXAMPLE.read_text(encoding="utf-8"),
    )
    assert n == 1  # z's driver chip taken out: two chip selects are left
    two = w.wiring(parse_config(text, "two.toml"))
    assert two.boot == ("enable_uart=1", "dtparam=spi=on")
    assert "SPI0 CE2" not in " ".join(two.roles())


# --- the overlay it names -------------------------------------------------------------------


def test_the_overlay_gives_the_chip_selects_of_the_table() -> None:
    dts = w.OVERLAY.read_text(encoding="utf-8")
    assert w.overlay_chip_selects(dts) == (8, 7, 24)
    assert w.wiring().roles()["motor 2 (z) chip select, SPI0 CE2"] == 24
    broken = dts.replace("<8 7 24>", "<8 7 25>")
    with pytest.raises(ValueError, match="brcm,pins"):
        w.overlay_chip_selects(broken)
    assert f"dtoverlay={w.OVERLAY_NAME}" in dts  # its own install line names it so


def test_the_overlay_compiles(tmp_path: Path) -> None:
    dtc = shutil.which("dtc")
    if dtc is None:
        pytest.skip("no dtc (apt install device-tree-compiler): the overlay is not compiled")
    out = subprocess.run(
        [dtc, "-@", "-I", "dts", "-O", "dtb", "-o", str(tmp_path / "o.dtbo"), str(w.OVERLAY)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0 and out.stderr == "", out.stderr
    dump = subprocess.run(
        [dtc, "-I", "dtb", "-O", "dts", str(tmp_path / "o.dtbo")],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    assert "brcm,pins = <0x08 0x07 0x18>;" in dump  # GPIO 8, 7, 24
    assert 'spi0 = "/fragment@1:target:0";' in dump and "spidev@2" in dump


# --- one table, pointed to -------------------------------------------------------------------


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = heading.lstrip("#").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    return {slug(h) for h in re.findall(r"^#{1,6} .*$", page.read_text(encoding="utf-8"), re.M)}


def test_the_pages_that_show_wiring_point_to_the_table() -> None:
    assert f"raspberry-pi.md#{slug(w.SECTION)}" == w.ANCHOR
    for page, link in POINTING.items():
        assert f"]({link})" in (REPO / page).read_text(encoding="utf-8"), page


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_links_into_raspberry_pi_md_name_its_sections(page: Path) -> None:
    targets = re.findall(r"\]\((?:docs/)?raspberry-pi\.md#([^)]+)\)", page.read_text("utf-8"))
    targets += re.findall(r"\]\(#([^)]+)\)", page.read_text("utf-8")) if page == w.PAGE else []
    missing = set(targets) - anchors(w.PAGE)
    assert not missing, f"{_rel(page)} links to sections raspberry-pi.md does not have: {missing}"


WIRING_HEADING = re.compile(r"\bGPIO\b|\bBCM\b|header pin|Pi pin", re.I)


def wiring_tables(text: str) -> list[str]:
    """The header rows of the Markdown tables of ``text`` that have a wiring column."""
    rows = text.splitlines()
    return [
        row
        for row, below in zip(rows, [*rows[1:], ""], strict=True)
        if row.startswith("|") and re.match(r"^\|[\s:|-]+\|$", below) and WIRING_HEADING.search(row)
    ]


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_no_other_wiring_table(page: Path) -> None:
    found = wiring_tables(outside_table(page.read_text(encoding="utf-8")))
    assert not found, f"{_rel(page)}: a wiring table of its own: {found}; point to {w.ANCHOR}"


# --- no GPIO for another role ----------------------------------------------------------------


@dataclass(frozen=True)
class Claim:
    where: str
    role: str
    gpio: int | None


def example_roles() -> dict[str, int | None]:
    """Every role of the example (as the table has it) under its doc-facing key: motor
    name + key (``x.step``), ``dc.in1``, ``pin.0``."""
    out: dict[str, int | None] = {}
    for what, gpio in w.wiring().roles().items():
        m = re.fullmatch(r"motor \d+ \((\w+)\) (STEP|DIR|EN|end stop min|end stop max)", what)
        if m:
            key = {"STEP": "step", "DIR": "dir", "EN": "enable"}.get(m.group(2))
            key = key or "endstop_" + m.group(2).split()[-1]
            out[f"{m.group(1)}.{key}"] = gpio
        elif what.startswith("DC motor "):
            out["dc." + what.split()[-1].lower()] = gpio
        elif re.fullmatch(r"pin \d+", what):
            out["pin." + what.split()[1]] = gpio
    for key in ("x", "y", "z"):  # wired nowhere: none may be named
        out.setdefault(f"{key}.endstop_max", None)
    return out


def toml_claims(text: str, where: str) -> list[Claim]:
    """What the TOML blocks of a page wire, by the example's role keys."""
    claims = []
    for block in re.findall(r"^```toml\n(.*?)^```", text, re.M | re.S):
        try:
            doc = tomllib.loads(block)
        except tomllib.TOMLDecodeError:
            continue  # not a config (an excerpt); prose and the loader's tests cover those
        for m in doc.get("motors", []):
            for key, line in m.get("gpiod", {}).items():
                if key in ("step", "dir", "enable", "endstop_min", "endstop_max") and line:
                    claims.append(Claim(where, f"{m.get('name')}.{key}", _gpio(line)))
        for key, line in doc.get("gpiod", {}).get("dc", {}).items():
            if key in ("in1", "in2", "en") and line:
                claims.append(Claim(where, f"dc.{key}", _gpio(line)))
        for p in doc.get("pins", []):
            if "line" in p.get("gpiod", {}):
                claims.append(Claim(where, f"pin.{p['number']}", _gpio(p["gpiod"]["line"])))
    return claims


def _gpio(line: str) -> int | None:
    try:
        return w.gpio_of(LineRef.parse(line))
    except (ValueError, w.WiringError):
        return None


#: a role word of the prose, the GPIOs the example gives that role (by ``classes()``)
ROLE = (
    r"(STEP|DIR|EN|ENABLE|IN1|IN2|CE\d|TXD|RXD|SCLK|MOSI|MISO|end ?stop"
    r"|(?<!header )pins? \d+(?:/\d+)*)"
)
GPIO = r"GPIO(\d+)(?:/\d+)*"
#: a role word, then its GPIO ("STEP GPIO17", "CE0 = GPIO8", "EN on GPIO21": groups 1, 2), or
#: a GPIO, then its role word ("GPIO14 TXD", "GPIO8 (CE0)": groups 3, 4)
PAIR = re.compile(
    rf"\b{ROLE}\b[\s:=`']*(?:on |at |is )?[\s`']*\b{GPIO}\b|\b{GPIO}\b[\s(`']*\b{ROLE}\b", re.I
)
CASE_SENSITIVE = ("STEP", "DIR", "EN", "ENABLE", "IN1", "IN2", "TXD", "RXD", "SCLK", "MOSI", "MISO")


def classes() -> dict[str, set[int]]:
    """role word -> the GPIOs the example (with the board's UART and SPI) gives it."""
    out: dict[str, set[int]] = {}
    for what, gpio in w.wiring().roles().items():
        if gpio is None:
            continue
        words = {
            "STEP": " STEP" in what,
            "DIR": " DIR" in what,
            "EN": what.endswith(" EN"),
            "ENABLE": what.endswith(" EN"),
            "IN1": what.endswith("IN1"),
            "IN2": what.endswith("IN2"),
            "TXD": what.endswith("TXD"),
            "RXD": what.endswith("RXD"),
            "SCLK": what.endswith("SCLK"),
            "MOSI": what.endswith("MOSI"),
            "MISO": what.endswith("MISO"),
            "ENDSTOP": "end stop" in what,
        }
        for word, yes in words.items():
            if yes:
                out.setdefault(word, set()).add(gpio)
        cs = re.search(r"(CE\d)$", what)
        if cs:
            out.setdefault(cs.group(1), set()).add(gpio)
        if re.fullmatch(r"pin \d+", what):
            out[what.upper()] = {gpio}
    return out


def prose_claims(text: str, where: str) -> list[tuple[str, str, int]]:
    """(where, role word, GPIO) for each role named right beside a GPIO in ``text``."""
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        for m in PAIR.finditer(line):
            role, gpio = m.group(1) or m.group(4), m.group(2) or m.group(3)
            if role.upper() in CASE_SENSITIVE and role != role.upper():
                continue  # "step", "dir" in prose: words, not the signals
            key = re.sub(r"^END ?STOP$", "ENDSTOP", role.upper())
            key = re.sub(r"^PINS? (\d+).*", r"PIN \1", key)
            found.append((f"{where}:{n}", key, int(gpio)))
    return found


def conflicts(text: str, where: str) -> list[str]:
    """What ``text`` says against the example."""
    roles, cls = example_roles(), classes()
    bad = [
        f"{c.where}: {c.role} is GPIO{c.gpio} there, {_show(roles[c.role])} in the example"
        for c in toml_claims(text, where)
        if c.role in roles and c.gpio != roles[c.role]
    ]
    bad += [
        f"{at}: {role} GPIO{gpio}; the example's {role}: {sorted(cls.get(role, set()))}"
        for at, role, gpio in prose_claims(text, where)
        if gpio not in cls.get(role, set())
    ]
    return bad


def _show(gpio: int | None) -> str:
    return "none" if gpio is None else f"GPIO{gpio}"


def example_comments() -> str:
    lines = w.EXAMPLE.read_text(encoding="utf-8").splitlines()
    return "\n".join(line.split("#", 1)[1] if "#" in line else "" for line in lines)


@pytest.mark.parametrize("page", [*PAGES, w.EXAMPLE], ids=_rel)
def test_no_page_names_a_gpio_for_a_role_the_example_gives_another(page: Path) -> None:
    text = page.read_text(encoding="utf-8") if page != w.EXAMPLE else example_comments()
    bad = conflicts(outside_table(text), _rel(page))
    assert not bad, "\n".join(bad)


def test_the_role_checks_see_what_they_look_for() -> None:
    """The checks would have caught what issue 35 found (docs/raspberry-pi.md before it)."""
    old = (
        "| end stop x min / y min | 5 / 6 | 29 / 31 | switch to GND (active low) |\n"
        "the x end stop GPIO5, y STEP GPIO23, driver EN on GPIO22, pins 0/1 on GPIO16\n"
    )
    bad = conflicts(old, "old")
    assert [b.split(";")[0] for b in bad] == [
        "old:2: ENDSTOP GPIO5",
        "old:2: STEP GPIO23",
        "old:2: EN GPIO22",
        "old:2: PIN 0 GPIO16",
    ]
    assert wiring_tables("| function | GPIO (BCM) | header pin | to |\n| --- | --- | --- | --- |")
    snippet = '```toml\n[[motors]]\nname = "x"\n  [motors.gpiod]\n  enable = "gpiochip0:4"\n```\n'
    assert conflicts(snippet, "s") == ["s: x.enable is GPIO4 there, none in the example"]
    good = "GPIO14 TXD, GPIO15 RXD; CE0 = GPIO8; STEP GPIO17, DIR GPIO27; pin 0 on GPIO4"
    assert conflicts(good, "good") == [] and len(prose_claims(good, "good")) == 6
