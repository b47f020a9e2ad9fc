"""The package's documents and the units' Documentation= lines, on a root laid out as debian/
installs them (debian/motorctl.docs, the units debian/rules installs, the manual pages of
debian/motorctl.manpages), checked by tests/deb/check_docs.py: the checker make test-deb runs
in the installed root. Here it runs on made-up roots: the repository's documents as the
package lays them out (every link between them resolves, every Documentation= target opens),
and roots with what issue 35 found (a document compressed to .gz under a Documentation= link,
a document missing) and other faults the checker must name.
"""

from __future__ import annotations

import gzip
import re
import shutil
from pathlib import Path

import pytest

from tests.deb.check_docs import main
from tests.support import REPO

DEBIAN = REPO / "debian"
DOC_DIR = Path("usr/share/doc/motorctl")


def shipped_docs() -> list[str]:
    """Every document the package must ship: README.md and all of docs/ (examples too)."""
    docs = ["README.md"]
    docs += sorted(str(p.relative_to(REPO)) for p in (REPO / "docs").rglob("*") if p.is_file())
    return docs


def shipped_units() -> list[str]:
    """The unit files debian/rules installs (their names)."""
    rules = (DEBIAN / "rules").read_text()
    return re.findall(r"install -D -m 0644 systemd/(\S+\.(?:service|timer)) ", rules)


def lay_out(root: Path) -> list[str]:
    """``root`` laid out as the package installs its documents, units and manual pages; the
    check_docs.py arguments for it."""
    docs = root / DOC_DIR
    docs.mkdir(parents=True)
    for entry in (DEBIAN / "motorctl.docs").read_text().split():
        source = REPO / entry
        if source.is_dir():
            shutil.copytree(source, docs / source.name)
        else:
            shutil.copy(source, docs / source.name)
    units = root / "usr/lib/systemd/system"
    units.mkdir(parents=True)
    for name in shipped_units():
        shutil.copy(REPO / "systemd" / name, units / name)
    for page in (DEBIAN / "motorctl.manpages").read_text().split():
        name = Path(page).name  # e.g. motorctld.1, made by help2man in debian/rules
        folder = root / "usr/share/man" / f"man{name.rsplit('.', 1)[1]}"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{name}.gz").write_bytes(gzip.compress(b'.TH MOTORCTLD "1"\n'))
    unit_args = [
        arg for name in shipped_units() for arg in ("--unit", f"/{units.relative_to(root)}/{name}")
    ]
    return ["--root", str(root), "--source", str(REPO), *unit_args, "--", *shipped_docs()]


def test_every_unit_file_in_systemd_is_installed() -> None:
    assert sorted(shipped_units()) == sorted(
        p.name for p in (REPO / "systemd").iterdir() if p.suffix in (".service", ".timer")
    )


def test_the_package_layout_passes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(lay_out(tmp_path)) == 0, capsys.readouterr().out
    out = capsys.readouterr().out
    assert "link: /usr/share/doc/motorctl/docs/raspberry-pi.md -> examples/raspberry-pi.toml" in out
    assert (
        "motorctld.service: Documentation=file:///usr/share/doc/motorctl/docs/service.md: opens"
        in out
    )


def fails(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert main(args) == 1
    return capsys.readouterr().out


def test_a_document_compressed_under_a_documentation_link_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 35: service.md installed as service.md.gz (dh_compress), the unit's link dead."""
    args = lay_out(tmp_path)
    page = tmp_path / DOC_DIR / "docs" / "service.md"
    page.with_name("service.md.gz").write_bytes(gzip.compress(page.read_bytes()))
    page.unlink()
    out = fails(args, capsys)
    assert "PROBLEM: docs/service.md: compressed to service.md.gz" in out
    assert (
        "PROBLEM: motorctld.service: Documentation=file:///usr/share/doc/motorctl/docs/service.md:"
        " service.md.gz is installed in its place" in out
    )
    assert "docs/raspberry-pi.md -> service.md#the-unit: no such file" in out


def test_a_document_left_out_fails(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = lay_out(tmp_path)
    (tmp_path / DOC_DIR / "docs" / "examples" / "raspberry-pi.toml").unlink()
    out = fails(args, capsys)
    assert "PROBLEM: docs/examples/raspberry-pi.toml: not installed" in out
    assert "docs/raspberry-pi.md -> examples/raspberry-pi.toml: no such file" in out


def test_a_changed_document_fails(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = lay_out(tmp_path)
    (tmp_path / DOC_DIR / "README.md").write_text("# motorctl\n")
    assert "README.md differs from the repository's README.md" in fails(args, capsys)


def test_a_missing_manual_page_and_a_web_target_fail(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = lay_out(tmp_path)
    (tmp_path / "usr/share/man/man1/motorctld.1.gz").unlink()
    unit = tmp_path / "usr/lib/systemd/system/motorctl-metrics.timer"
    unit.write_text(unit.read_text() + "[Unit]\nDocumentation=https://example.org/motorctl\n")
    out = fails(args, capsys)
    assert "motorctld.service: Documentation=man:motorctld(1): no manual page motorctld(1)" in out
    assert "Documentation=https://example.org/motorctl: not a file: or man: target" in out
