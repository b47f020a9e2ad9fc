"""One small line-request API over both libgpiod Python bindings (v1 1.6 and v2 >= 2).

``gpiod`` is imported only when :func:`load_api` is called, here and in the binding it
picks (binding_v2.py, binding_v1.py: each binding's :class:`GpioApi` and :class:`LineRequest`).
:class:`GpioApi` finds chips and lines and makes :class:`LineRequest` objects; the backend
(:mod:`motorctl.hal.backends.gpiod.backend`) builds pins, bridges, end stops and step ports on
them. Levels here are physical (no active-low inversion): the caller inverts.

Threads: a request belongs to the part that made it (pin, bridge, step port, end stop);
that part's owner calls it. Calls block only on the GPIO character device's ioctls,
except :meth:`LineRequest.wait_events`, which blocks up to its timeout.
"""

from __future__ import annotations

import errno
import grp
import os
import select
from abc import ABC, abstractmethod
from dataclasses import dataclass

from motorctl.hal.backends.gpiod.boards import board_of, chip_number, describe_chip
from motorctl.hal.backends.gpiod.wiring import AS_IS, LineRef, ResolvedLine
from motorctl.hal.compiled_lines import ChardevRequest
from motorctl.hal.interfaces import HalError

DEV = "/dev"


@dataclass(frozen=True)
class LineSettings:
    """How one line is requested. ``debounce_us`` is honoured where the API has it (v2)."""

    output: bool = False
    value: bool = False
    bias: str = AS_IS
    edges: bool = False
    debounce_us: int = 0


@dataclass(frozen=True)
class Edge:
    """An edge on an input line: kernel timestamp (CLOCK_MONOTONIC, ns) and new level."""

    offset: int
    rising: bool
    timestamp_ns: int


@dataclass(frozen=True)
class ChipInfo:
    """A GPIO chip as the kernel names it: its device path, name, label and line count."""

    path: str
    name: str
    label: str
    num_lines: int


@dataclass(frozen=True)
class LineInfo:
    """One line of a chip as the kernel reports it: offset, name, whether (and by whom)
    it is used, and its direction."""

    offset: int
    name: str
    used: bool
    consumer: str
    output: bool


class LineRequest(ABC):
    """Lines of one chip requested together."""

    def __init__(self, chip_path: str, settings: dict[int, LineSettings]) -> None:
        self.chip_path = chip_path
        self.settings = dict(settings)

    @abstractmethod
    def set_values(self, values: dict[int, bool]) -> None: ...

    @abstractmethod
    def get_values(self, offsets: list[int]) -> list[bool]: ...

    @abstractmethod
    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        """Change one line's settings (direction), keeping the others."""

    @abstractmethod
    def fileno(self) -> int:
        """A descriptor that is readable when edge events are pending (event requests)."""

    @abstractmethod
    def read_events(self) -> list[Edge]:
        """Pending edge events (call when :meth:`fileno` is readable)."""

    @abstractmethod
    def release(self) -> None: ...

    def wait_events(self, timeout_s: float) -> list[Edge]:
        """Edge events arriving within ``timeout_s`` (none: an empty list)."""
        r, _, _ = select.select([self.fileno()], [], [], max(0.0, timeout_s))
        return self.read_events() if r else []

    def raw(self) -> ChardevRequest | str:
        """The request as the kernel knows it, for a compiled core's ioctls (its descriptor,
        uAPI, lines in order, driven levels), or why it cannot be had."""
        return "this libgpiod binding does not give the request's descriptor"


#: what /proc/self/fd shows for a GPIO chardev request, by uAPI (gpiolib-cdev.c's names)
_KINDS = {"anon_inode:gpio-line": 2, "anon_inode:gpio-linehandle": 1, "anon_inode:gpio-event": 1}


def fd_kind(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError as exc:
        return f"unreadable ({exc.strerror})"


def chardev_request(
    fd: int, offsets: tuple[int, ...], levels: tuple[bool, ...] = ()
) -> ChardevRequest | str:
    """``fd`` as a GPIO chardev request when the kernel says it is one, else why not."""
    kind = fd_kind(fd)
    uapi = _KINDS.get(kind)
    if uapi is None:
        return f"descriptor {fd} is not a GPIO line request ({kind})"
    return ChardevRequest(fd, uapi, offsets, levels)


class GpioApi(ABC):
    """The libgpiod Python binding in use."""

    name: str
    version: str

    def chip_paths(self) -> list[str]:
        """The chips' character devices, by number: not the links to them (Raspberry Pi OS
        links /dev/gpiochip4 to gpiochip0 on a Pi 5; :meth:`aliases`), as gpiodetect does."""
        return [p for p in self._dev_chips() if not os.path.islink(p)]

    def aliases(self) -> dict[str, str]:
        """Links in /dev to a chip: ``{"gpiochip4": "/dev/gpiochip0"}``."""
        out = {}
        for path in self._dev_chips():
            if os.path.islink(path):
                target = os.path.realpath(path)
                head, name = os.path.split(target)
                if head == DEV and chip_number(name) is not None:
                    out[os.path.basename(path)] = target
        return out

    def _dev_chips(self) -> list[str]:
        try:
            names = sorted(os.listdir(DEV), key=_chip_sort_key)
        except OSError:
            return []
        return [f"{DEV}/{n}" for n in names if chip_number(n) is not None]

    @abstractmethod
    def chip_info(self, path: str) -> ChipInfo: ...

    @abstractmethod
    def line_info(self, path: str, offset: int) -> LineInfo: ...

    @abstractmethod
    def line_names(self, path: str) -> list[str]:
        """Every line's name on one chip, by offset ("" for an unnamed line)."""

    @abstractmethod
    def _request(
        self, path: str, consumer: str, settings: dict[int, LineSettings]
    ) -> LineRequest: ...

    # -- finding lines ---------------------------------------------------------
    def chips(self) -> list[ChipInfo]:
        out = []
        for path in self.chip_paths():
            try:
                out.append(self.chip_info(path))
            except OSError as exc:
                raise open_error(path, exc) from exc
        return out

    def resolve(self, lines: list[tuple[str, LineRef]]) -> list[ResolvedLine]:
        """Find every line on the kernel's chips; any that cannot be found is an error that
        lists the chips there are (number, label, line count)."""
        chips = self.chips()
        names: dict[str, list[tuple[ChipInfo, int]]] = {}
        if any(ref.name is not None for _, ref in lines):
            for chip in chips:
                for off, name in enumerate(self.line_names(chip.path)):
                    if name:
                        names.setdefault(name, []).append((chip, off))
        aliases = self.aliases()
        out: list[ResolvedLine] = []
        for use, ref in lines:
            if ref.name is not None:
                found = names.get(ref.name, [])
                if not found:
                    raise HalError(
                        f"{use}: no GPIO line named {ref.name!r} on any chip "
                        f"({chip_list(chips)}); `gpioinfo` lists the names, or write "
                        "chip:offset"
                    )
                if len(found) > 1:
                    where = ", ".join(f"{c.name}:{o}" for c, o in found)
                    raise HalError(
                        f"{use}: line name {ref.name!r} is on several chips ({where}); "
                        "write chip:offset"
                    )
                chip, off = found[0]
            else:
                assert ref.chip is not None and ref.offset is not None
                chip, off = self._chip_of(use, ref.chip, ref.offset, chips, aliases), ref.offset
                if off >= chip.num_lines:
                    raise HalError(
                        f"{use}: {chip.name} [{chip.label}] has {chip.num_lines} lines "
                        f"(0..{chip.num_lines - 1}), no line {off} ({chip_list(chips)})"
                    )
            info = self.line_info(chip.path, off)
            out.append(ResolvedLine(use, ref, chip.path, off, chip.label, info.name))
        return out

    @staticmethod
    def _chip_of(
        use: str, ref: str, offset: int, chips: list[ChipInfo], aliases: dict[str, str]
    ) -> ChipInfo:
        """The chip a config names by its name (``gpiochip0``), a link to it in /dev
        (``gpiochip4`` -> gpiochip0) or its label (``pinctrl-rp1``)."""
        path = aliases.get(ref)
        match = [c for c in chips if ref == c.name or c.path == path]
        if not match:
            match = [c for c in chips if ref == c.label]
            if len(match) > 1:
                raise HalError(
                    f"{use}: chip label {ref!r} is on several chips "
                    f"({', '.join(c.name for c in match)}); write the chip's name"
                )
        if not match:
            hint = "check the name with `gpiodetect`"
            if chip_number(ref) is not None:
                header = next((c for c in chips if board_of(c) is not None), None)
                label = header.label if header is not None else "LABEL"
                hint = (
                    "chip numbers change between kernels (a Raspberry Pi 5's RP1 was gpiochip4 "
                    f"before 6.6.45, gpiochip0 after): write the chip's label ({label}:{offset}) "
                    "or the line's name (`gpioinfo` lists them)"
                )
            raise HalError(f"{use}: no GPIO chip {ref!r} ({chip_list(chips)}); {hint}")
        return match[0]

    def check_free(self, lines: list[ResolvedLine]) -> None:
        """Every line resolves to a distinct, unheld line; otherwise an error that names it."""
        seen: dict[tuple[str, int], str] = {}
        for line in lines:
            key = (line.chip_path, line.offset)
            if key in seen:
                raise HalError(
                    f"{line.use} and {seen[key]} are the same line "
                    f"({_where(line)}); each line can have one use"
                )
            seen[key] = line.use
            info = self.line_info(line.chip_path, line.offset)
            if info.used:
                raise HalError(busy_message(line, info.consumer))

    def request(self, consumer: str, lines: list[tuple[ResolvedLine, LineSettings]]) -> LineRequest:
        """Request lines of ONE chip together; errors name the line, the holder and the fix."""
        path = lines[0][0].chip_path
        assert all(r.chip_path == path for r, _ in lines)
        settings = {r.offset: s for r, s in lines}
        try:
            return self._request(path, consumer, settings)
        except OSError as exc:
            if exc.errno == errno.EBUSY:
                for r, _ in lines:
                    info = self.line_info(path, r.offset)
                    if info.used:
                        raise HalError(busy_message(r, info.consumer)) from exc
            raise open_error(path, exc, ", ".join(r.use for r, _ in lines)) from exc


def _chip_sort_key(name: str) -> tuple[int, str]:
    number = chip_number(name)
    return (number, name) if number is not None else (1 << 30, name)


def chip_list(chips: list[ChipInfo]) -> str:
    """The chips there are, for an error: ``chips: gpiochip0 [pinctrl-rp1] 54 lines, ...``."""
    if not chips:
        return "the kernel shows no GPIO chips in /dev"
    return "chips: " + ", ".join(describe_chip(c) for c in chips)


def _where(line: ResolvedLine) -> str:
    name = f" {line.line_name!r}" if line.line_name else ""
    return f"{os.path.basename(line.chip_path)}:{line.offset}{name}"


def busy_message(line: ResolvedLine, consumer: str) -> str:
    holder = repr(consumer) if consumer else "an unnamed consumer (kernel driver or a process)"
    return (
        f"{line.use}: line {_where(line)} is already in use by {holder}; stop that program "
        "(see `gpioinfo`), or remove the device-tree overlay that claims it, or wire another "
        "line"
    )


def open_error(path: str, exc: OSError, use: str = "") -> HalError:
    """An OSError from opening or requesting on ``path`` as an error that says the fix."""
    what = f"{use}: " if use else ""
    if exc.errno in (errno.EACCES, errno.EPERM):
        try:
            group = grp.getgrgid(os.stat(path).st_gid).gr_name
        except (OSError, KeyError):
            group = "gpio"
        return HalError(
            f"{what}permission denied on {path}: add the daemon's user to group {group!r} "
            f"(sudo usermod -aG {group} USER, then log in again) or run it as the packaged "
            "service user"
        )
    if exc.errno == errno.ENOENT:
        return HalError(f"{what}{path} does not exist; check the chip with `gpiodetect`")
    return HalError(f"{what}{path}: {exc.strerror or exc}")


def load_api(which: str = "auto") -> GpioApi:
    """The libgpiod binding: ``v2``, ``v1``, or ``auto`` (whichever ``import gpiod`` gives)."""
    if which not in ("auto", "v1", "v2"):
        raise HalError(f"gpiod api must be auto, v1 or v2, not {which!r}")
    try:
        import gpiod
    except ImportError as exc:
        raise HalError(
            "the gpiod backend needs libgpiod's Python binding: `pip install gpiod` (v2 API, "
            "or motorctl[hardware]) or `apt install python3-libgpiod` (Debian/Raspberry Pi OS)"
        ) from exc
    have = "v2" if hasattr(gpiod, "request_lines") else "v1"
    if which != "auto" and which != have:
        raise HalError(
            f"[gpiod] api = {which!r} but the installed gpiod module has the {have} "
            f"API ({getattr(gpiod, '__file__', '?')}); install the other one or set "
            'api = "auto"'
        )
    if have == "v2":
        from motorctl.hal.backends.gpiod.binding_v2 import V2Api

        return V2Api(gpiod)
    from motorctl.hal.backends.gpiod.binding_v1 import V1Api

    return V1Api(gpiod)
