"""One small line-request API over both libgpiod Python bindings (v1 1.6 and v2 >= 2).

``gpiod`` is imported only here and only when :func:`load_api` is called. :class:`GpioApi`
finds chips and lines and makes :class:`LineRequest` objects; the backend
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
from datetime import timedelta
from typing import Any

from motorctl.hal.backends.gpiod.boards import board_of, chip_number, describe_chip
from motorctl.hal.backends.gpiod.wiring import LineRef, ResolvedLine
from motorctl.hal.interfaces import ChardevRequest, HalError

DEV = "/dev"


@dataclass(frozen=True)
class LineSettings:
    """How one line is requested. ``debounce_us`` is honoured where the API has it (v2)."""

    output: bool = False
    value: bool = False
    bias: str = "as-is"
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
    path: str
    name: str
    label: str
    num_lines: int


@dataclass(frozen=True)
class LineInfo:
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


def _fd_kind(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError as exc:
        return f"unreadable ({exc.strerror})"


def chardev_request(
    fd: int, offsets: tuple[int, ...], levels: tuple[bool, ...] = ()
) -> ChardevRequest | str:
    """``fd`` as a GPIO chardev request when the kernel says it is one, else why not."""
    kind = _fd_kind(fd)
    uapi = _KINDS.get(kind)
    if uapi is None:
        return f"descriptor {fd} is not a GPIO line request ({kind})"
    return ChardevRequest(fd, uapi, offsets, levels)


def _open_fds() -> dict[int, str]:
    """Open descriptors and what each is (the listing's own descriptor shows as gone: a
    later descriptor of that number is new)."""
    try:
        return {int(n): _fd_kind(int(n)) for n in os.listdir("/proc/self/fd")}
    except OSError:
        return {}


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
    return _V2(gpiod) if have == "v2" else _V1(gpiod)


# --------------------------------------------------------------------------------------------
# v2: PyPI gpiod >= 2, Debian trixie python3-libgpiod 2.x


class _V2(GpioApi):
    def __init__(self, gpiod: Any) -> None:
        self.g = gpiod
        self.name = "v2"
        self.version = str(getattr(gpiod, "__version__", "2"))
        from gpiod import line

        self.line = line

    def chip_info(self, path: str) -> ChipInfo:
        with self.g.Chip(path) as chip:
            info = chip.get_info()
            return ChipInfo(path, info.name, info.label, info.num_lines)

    def line_names(self, path: str) -> list[str]:
        with self.g.Chip(path) as chip:
            n = chip.get_info().num_lines
            return [chip.get_line_info(off).name or "" for off in range(n)]

    def line_info(self, path: str, offset: int) -> LineInfo:
        with self.g.Chip(path) as chip:
            i = chip.get_line_info(offset)
            return LineInfo(
                offset,
                i.name or "",
                i.used,
                i.consumer or "",
                i.direction == self.line.Direction.OUTPUT,
            )

    def settings(self, s: LineSettings) -> Any:
        L = self.line
        bias = {
            "as-is": L.Bias.AS_IS,
            "pull-up": L.Bias.PULL_UP,
            "pull-down": L.Bias.PULL_DOWN,
            "disabled": L.Bias.DISABLED,
        }[s.bias]
        kw: dict[str, Any] = {"bias": bias}
        if s.output:
            kw.update(
                direction=L.Direction.OUTPUT,
                output_value=L.Value.ACTIVE if s.value else L.Value.INACTIVE,
            )
        else:
            kw["direction"] = L.Direction.INPUT
            if s.edges:
                kw["edge_detection"] = L.Edge.BOTH
                if s.debounce_us:
                    kw["debounce_period"] = timedelta(microseconds=s.debounce_us)
        return self.g.LineSettings(**kw)

    def _request(self, path: str, consumer: str, settings: dict[int, LineSettings]) -> LineRequest:
        cfg = {off: self.settings(s) for off, s in settings.items()}
        req = self.g.request_lines(path, consumer=consumer, config=cfg)
        return _V2Request(self, path, settings, req)


class _V2Request(LineRequest):
    def __init__(self, api: _V2, path: str, settings: dict[int, LineSettings], req: Any) -> None:
        super().__init__(path, settings)
        self.api = api
        self.req = req
        Value = api.line.Value
        self.hi, self.lo, self.active = Value.ACTIVE, Value.INACTIVE, Value.ACTIVE
        self.rising = api.g.EdgeEvent.Type.RISING_EDGE

    def set_values(self, values: dict[int, bool]) -> None:
        hi, lo = self.hi, self.lo
        self.req.set_values({off: hi if v else lo for off, v in values.items()})

    def set_value(self, offset: int, level: bool) -> None:
        self.req.set_value(offset, self.hi if level else self.lo)

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [v == self.active for v in self.req.get_values(offsets)]

    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        self.settings[offset] = settings
        self.req.reconfigure_lines({o: self.api.settings(s) for o, s in self.settings.items()})

    def fileno(self) -> int:
        return int(self.req.fd)

    def raw(self) -> ChardevRequest | str:
        try:
            fd, offsets = int(self.req.fd), tuple(int(o) for o in self.req.offsets)
        except (AttributeError, TypeError, ValueError) as exc:
            return f"the gpiod binding gives no descriptor and offsets ({exc})"
        levels = tuple(self.settings[o].value for o in offsets if o in self.settings)
        return chardev_request(fd, offsets, levels if len(levels) == len(offsets) else ())

    def read_events(self) -> list[Edge]:
        rising = self.rising
        return [
            Edge(e.line_offset, e.event_type == rising, e.timestamp_ns)
            for e in self.req.read_edge_events()
        ]

    def release(self) -> None:
        self.req.release()


# --------------------------------------------------------------------------------------------
# v1: Debian bookworm / Raspberry Pi OS python3-libgpiod 1.6


class _V1(GpioApi):
    def __init__(self, gpiod: Any) -> None:
        self.g = gpiod
        self.name = "v1"
        self.version = str(getattr(gpiod, "__version__", "1"))

    def _chip(self, path: str) -> Any:
        return self.g.Chip(path)

    def chip_info(self, path: str) -> ChipInfo:
        chip = self._chip(path)
        try:
            return ChipInfo(path, chip.name(), chip.label(), chip.num_lines())
        finally:
            chip.close()

    def line_names(self, path: str) -> list[str]:
        chip = self._chip(path)
        try:
            return [chip.get_line(off).name() or "" for off in range(chip.num_lines())]
        finally:
            chip.close()

    def line_info(self, path: str, offset: int) -> LineInfo:
        chip = self._chip(path)
        try:
            ln = chip.get_line(offset)
            return LineInfo(
                offset,
                ln.name() or "",
                ln.is_used(),
                ln.consumer() or "",
                ln.direction() == self.g.Line.DIRECTION_OUTPUT,
            )
        finally:
            chip.close()

    def flags(self, s: LineSettings) -> int:
        g = self.g
        flags: dict[str, int] = {
            "as-is": 0,
            "pull-up": g.LINE_REQ_FLAG_BIAS_PULL_UP,
            "pull-down": g.LINE_REQ_FLAG_BIAS_PULL_DOWN,
            "disabled": g.LINE_REQ_FLAG_BIAS_DISABLE,
        }
        return flags[s.bias]

    def request_one(self, chip: Any, consumer: str, offset: int, s: LineSettings) -> Any:
        g = self.g
        ln = chip.get_line(offset)
        if s.output:
            ln.request(
                consumer=consumer,
                type=g.LINE_REQ_DIR_OUT,
                flags=self.flags(s),
                default_val=int(s.value),
            )
        else:
            kind = g.LINE_REQ_EV_BOTH_EDGES if s.edges else g.LINE_REQ_DIR_IN
            ln.request(consumer=consumer, type=kind, flags=self.flags(s))
        return ln

    def _request(self, path: str, consumer: str, settings: dict[int, LineSettings]) -> LineRequest:
        chip = self._chip(path)
        try:
            if any(s.edges for s in settings.values()) or len(settings) == 1:
                # v1 event requests are per line: one line (end stops, pins) per request.
                if len(settings) != 1:
                    raise HalError("v1: an edge-event request holds one line")
                ((off, s),) = settings.items()
                return _V1Request(
                    self,
                    path,
                    settings,
                    chip,
                    {off: self.request_one(chip, consumer, off, s)},
                    None,
                )
            offs = list(settings)
            g = self.g
            if not all(settings[o].output for o in offs):
                raise HalError("v1: a multi-line request is outputs only")
            bulk = chip.get_lines(offs)
            before = _open_fds()
            bulk.request(
                consumer=consumer,
                type=g.LINE_REQ_DIR_OUT,
                default_vals=[int(settings[o].value) for o in offs],
            )
            lines = {o: ln for o, ln in zip(offs, bulk.to_list(), strict=True)}
            req = _V1Request(self, path, settings, chip, lines, bulk)
            # libgpiod 1.6's binding does not give an output handle's descriptor: it is the
            # one GPIO line handle this request opened (a compiled core writes it)
            handle = "anon_inode:gpio-linehandle"
            new = [fd for fd, kind in _open_fds().items() if kind == handle != before.get(fd)]
            req.handle_fd = new[0] if len(new) == 1 else None
            return req
        except BaseException:
            chip.close()
            raise


class _V1Request(LineRequest):
    """v1 line handles. A multi-line handle sets all its lines at once (the v1 uAPI), so the
    driven levels of all of them are kept here and always written together."""

    def __init__(
        self,
        api: _V1,
        path: str,
        settings: dict[int, LineSettings],
        chip: Any,
        lines: dict[int, Any],
        bulk: Any,
    ) -> None:
        super().__init__(path, settings)
        self.api = api
        self.chip = chip
        self.lines = lines
        self.bulk = bulk
        self.levels = {o: s.value for o, s in settings.items()}
        self.order = list(lines)
        self.consumer = ""
        self.handle_fd: int | None = None  # a multi-line output handle's, when found

    def set_values(self, values: dict[int, bool]) -> None:
        self.levels.update(values)
        if self.bulk is not None:
            levels = self.levels
            self.bulk.set_values([int(levels[o]) for o in self.order])
        else:
            for o, v in values.items():
                self.lines[o].set_value(int(v))

    def set_value(self, offset: int, level: bool) -> None:
        self.set_values({offset: level})

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [bool(self.lines[o].get_value()) for o in offsets]

    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        # v1 has no reconfigure in the uAPI we rely on: release and request again.
        if self.bulk is not None:
            raise HalError("v1: reconfigure is for single-line requests")
        line = self.lines[offset]
        consumer = line.consumer() or "motorctl"
        line.release()
        self.settings[offset] = settings
        self.levels[offset] = settings.value
        self.lines[offset] = self.api.request_one(self.chip, consumer, offset, settings)

    def fileno(self) -> int:
        (line,) = self.lines.values()
        return int(line.event_get_fd())

    def raw(self) -> ChardevRequest | str:
        if self.bulk is not None:
            if self.handle_fd is None:
                return "the line handle's descriptor was not found (libgpiod v1)"
            levels = tuple(self.levels[o] for o in self.order)
            return chardev_request(self.handle_fd, tuple(self.order), levels)
        ((off, line),) = self.lines.items()
        if not self.settings[off].edges:
            return "a single v1 output line gives no descriptor"
        return chardev_request(int(line.event_get_fd()), (off,))

    def read_events(self) -> list[Edge]:
        ((off, line),) = self.lines.items()
        rising = self.api.g.LineEvent.RISING_EDGE
        out: list[Edge] = []
        while True:
            r, _, _ = select.select([line.event_get_fd()], [], [], 0)
            if not r:
                return out
            ev = line.event_read()
            ts = int(ev.sec) * 1_000_000_000 + int(ev.nsec)
            out.append(Edge(off, ev.type == rising, ts))

    def release(self) -> None:
        try:
            if self.bulk is not None:
                self.bulk.release()
            else:
                for line in self.lines.values():
                    line.release()
        finally:
            self.chip.close()
