-- motorctl.lua: a Wireshark/tshark dissector for motorctl's trace files (docs/trace.md,
-- "Wireshark"): the pcapng files motorctld --trace and motorctl tap write, link type 147
-- (LINKTYPE_USER0), one packet per byte run with its direction in epb_flags.
--
-- It decodes what `motorctl trace` decodes, the same way: inbound runs (host -> device) are
-- cut into 10-byte command frames with the frame gap rule (a partial frame is dropped after
-- more than frame_gap_ms of silence), outbound runs into 5-byte answers, and each answer is
-- paired with the oldest unanswered frame and decoded for the command it answers. Each
-- command is named with its fields, each answer with what it means for that command
-- (ready/busy, the position, the pin level, the waypoint number, the error code by name),
-- every checksum is checked, and each answer links to its command (and back) with the round
-- trip time. Fields: motorctl.command, motorctl.motor, motorctl.position, ... (`tshark -G
-- fields | grep motorctl`); the field names and values match `motorctl trace --json`.
--
-- Settings: the recording's own settings are in the file's comments, which a dissector
-- cannot read; the preferences (Edit > Preferences > Protocols > MOTORCTL, or tshark -o
-- motorctl.frame_gap_ms:20) default to motorctld's defaults: CRC-8/SMBUS ("crc8"), the
-- checksum over R1..R3, strict padding, a 10 ms frame gap.
--
-- Runs on Wireshark 4.0 (Lua 5.2, Debian 12) and 4.4 (Lua 5.4, Debian 13). The Debian
-- package links it into Wireshark's global Lua plugin folder; by hand: copy it to
-- ~/.local/lib/wireshark/plugins/ or run `tshark -X lua_script:motorctl.lua -r FILE`.

local proto = Proto("motorctl", "motorctl UART protocol")

local DIR_SENT, DIR_RECV = 0, 1 -- pinfo.p2p_dir: epb_flags outbound (answers), inbound (commands)
local FRAME_LEN = 10
local RESPONSE_LEN = 5

local COMMANDS = {
    [0x00] = "InitMove", [0x01] = "MoveTo", [0x02] = "WaitMoved", [0x03] = "IsReady",
    [0x04] = "Move", [0x05] = "StopMove", [0x06] = "GetAbsPos", [0x07] = "SetPin",
    [0x08] = "GetPin", [0x09] = "ConfigPin", [0x0A] = "SaveHome", [0x0B] = "GoHome",
    [0x0C] = "SaveWayPoint", [0x0D] = "MoveToWayPoint", [0x0E] = "DcMove",
}

-- each command's parameters after B0, in wire order: {field, kind}
local LAYOUT = {
    [0x00] = { { "motor", "u8" }, { "direction", "dir" }, { "speed", "u8" }, { "acc", "u8" }, { "dec", "u8" } },
    [0x01] = { { "motor", "u8" }, { "direction", "dir" }, { "position", "s24" }, { "speed", "u8" },
               { "acc", "u8" }, { "dec", "u8" } },
    [0x02] = { { "motor", "u8" }, { "timeout_ms", "u16" } },
    [0x03] = { { "motor", "u8" } },
    [0x04] = { { "motor", "u8" }, { "direction", "dir" }, { "speed", "u8" }, { "acc", "u8" }, { "dec", "u8" } },
    [0x05] = { { "motor", "u8" }, { "hard", "bool" } },
    [0x06] = { { "motor", "u8" } },
    [0x07] = { { "pin", "u8" }, { "value", "level" } },
    [0x08] = { { "pin", "u8" } },
    [0x09] = { { "pin", "u8" }, { "output", "bool" } },
    [0x0A] = { { "motor", "u8" } },
    [0x0B] = { { "motor", "u8" } },
    [0x0C] = { { "motor", "u8" } },
    [0x0D] = { { "motor", "u8" }, { "waypoint", "u8" }, { "speed", "u8" }, { "acc", "u8" }, { "dec", "u8" } },
    [0x0E] = { { "direction", "dcdir" }, { "time_ms", "u16" }, { "hiz", "bool" } },
}
local SIZE = { u8 = 1, u16 = 2, s24 = 3, bool = 1, dir = 1, dcdir = 1, level = 1 }
local SHORT = { direction = "dir", position = "pos", value = "high" }

local ERRORS = {
    [0xE0] = "Full Buffer", [0xE1] = "Invalid Command", [0xE2] = "Invalid Address",
    [0xE3] = "Motor not ready", [0xE4] = "Motor Error", [0xE5] = "Full Way Point Buffer",
    [0xE6] = "Invalid Way Point",
}
local ERROR_TEXT = {}
for code, name in pairs(ERRORS) do
    ERROR_TEXT[code] = string.format("E%d %s", code - 0xE0, name)
end

-- the reveng catalogue's CRC-8s, as protocol/crc.py has them (tests compare the two)
local CRCS = {
    { name = "CRC-8/AUTOSAR", poly = 0x2F, init = 0xFF, refin = false, refout = false, xorout = 0xFF },
    { name = "CRC-8/BLUETOOTH", poly = 0xA7, init = 0x00, refin = true, refout = true, xorout = 0x00 },
    { name = "CRC-8/CDMA2000", poly = 0x9B, init = 0xFF, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/DARC", poly = 0x39, init = 0x00, refin = true, refout = true, xorout = 0x00 },
    { name = "CRC-8/DVB-S2", poly = 0xD5, init = 0x00, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/GSM-A", poly = 0x1D, init = 0x00, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/GSM-B", poly = 0x49, init = 0x00, refin = false, refout = false, xorout = 0xFF },
    { name = "CRC-8/HITAG", poly = 0x1D, init = 0xFF, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/I-432-1", poly = 0x07, init = 0x00, refin = false, refout = false, xorout = 0x55 },
    { name = "CRC-8/I-CODE", poly = 0x1D, init = 0xFD, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/LTE", poly = 0x9B, init = 0x00, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/MAXIM-DOW", poly = 0x31, init = 0x00, refin = true, refout = true, xorout = 0x00 },
    { name = "CRC-8/MIFARE-MAD", poly = 0x1D, init = 0xC7, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/NRSC-5", poly = 0x31, init = 0xFF, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/OPENSAFETY", poly = 0x2F, init = 0x00, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/ROHC", poly = 0x07, init = 0xFF, refin = true, refout = true, xorout = 0x00 },
    { name = "CRC-8/SAE-J1850", poly = 0x1D, init = 0xFF, refin = false, refout = false, xorout = 0xFF },
    { name = "CRC-8/SMBUS", poly = 0x07, init = 0x00, refin = false, refout = false, xorout = 0x00 },
    { name = "CRC-8/TECH-3250", poly = 0x1D, init = 0xFF, refin = true, refout = true, xorout = 0x00 },
    { name = "CRC-8/WCDMA", poly = 0x9B, init = 0x00, refin = true, refout = true, xorout = 0x00 },
}
local SMBUS = 18 -- CRCS[18]: "crc8", the protocol's checksum
local NONE = 0 -- the checksum preference's value for "none"

-- fields --------------------------------------------------------------------------------------

local CHECKSUM_STATUS = { [0] = "Bad", [1] = "Good", [2] = "Unverified" }
local f = {
    kind = ProtoField.string("motorctl.kind", "Kind",
        base.ASCII, "command, bad_frame, gap, answer, bad_answer, extra_answer or lost"),
    frame = ProtoField.uint32("motorctl.frame", "Frame number", base.DEC, nil, nil,
        "the command frame's number in the conversation (1 = the first), for answers the one answered"),
    command = ProtoField.string("motorctl.command", "Command"),
    code = ProtoField.uint8("motorctl.code", "Command code", base.HEX, COMMANDS),
    motor = ProtoField.uint8("motorctl.motor", "Motor"),
    direction = ProtoField.string("motorctl.direction", "Direction"),
    position = ProtoField.int32("motorctl.position", "Position (steps)"),
    speed = ProtoField.uint8("motorctl.speed", "Speed"),
    acc = ProtoField.uint8("motorctl.acc", "Acceleration"),
    dec = ProtoField.uint8("motorctl.dec", "Deceleration"),
    pin = ProtoField.uint8("motorctl.pin", "Pin"),
    value = ProtoField.uint8("motorctl.value", "Level", base.DEC, { [0] = "low", [1] = "high" }),
    output = ProtoField.uint8("motorctl.output", "Output", base.DEC, { [0] = "input", [1] = "output" }),
    hard = ProtoField.uint8("motorctl.hard", "Hard stop", base.DEC, { [0] = "no (ramp)", [1] = "yes" }),
    timeout_ms = ProtoField.uint16("motorctl.timeout_ms", "Timeout (ms)"),
    time_ms = ProtoField.uint16("motorctl.time_ms", "Run time (ms)"),
    hiz = ProtoField.uint8("motorctl.hiz", "Coast at the end (GO_HiZ)", base.DEC, { [0] = "no (brake)", [1] = "yes" }),
    waypoint = ProtoField.uint8("motorctl.waypoint", "Waypoint"),
    padding = ProtoField.bytes("motorctl.padding", "Padding"),
    checksum = ProtoField.uint8("motorctl.checksum", "Checksum", base.HEX),
    checksum_status = ProtoField.uint8("motorctl.checksum.status", "Checksum status", base.DEC, CHECKSUM_STATUS),
    checksum_expected = ProtoField.uint8("motorctl.checksum.expected", "Checksum expected", base.HEX),
    frame_error = ProtoField.string("motorctl.frame_error", "Frame error",
        base.ASCII, "why the frame is answered E1: checksum, unknown, padding"),
    ack = ProtoField.uint8("motorctl.ack", "R0", base.HEX, { [0] = "error", [1] = "ACK" }),
    answer = ProtoField.string("motorctl.answer", "Answer"),
    ready = ProtoField.uint8("motorctl.ready", "Ready", base.DEC, { [0] = "busy", [1] = "ready" }),
    error_code = ProtoField.uint8("motorctl.error_code", "Error code", base.HEX, ERROR_TEXT),
    error_name = ProtoField.string("motorctl.error_name", "Error"),
    payload = ProtoField.bytes("motorctl.payload", "Payload (R1..R3)"),
    rtt = ProtoField.relative_time("motorctl.rtt", "Round trip",
        "from the last byte of the command frame to the answer"),
    request_in = ProtoField.framenum("motorctl.request_in", "Command in", base.NONE, frametype.REQUEST),
    response_in = ProtoField.framenum("motorctl.response_in", "Answer in", base.NONE, frametype.RESPONSE),
    partial = ProtoField.bytes("motorctl.partial", "Partial frame dropped"),
    lost = ProtoField.uint64("motorctl.lost", "Byte runs left out before this one (epb_dropcount)"),
}
local field_list = {}
for _, v in pairs(f) do
    field_list[#field_list + 1] = v
end
proto.fields = field_list

local e = {
    checksum = ProtoExpert.new("motorctl.checksum.bad.expert", "Bad checksum",
        expert.group.CHECKSUM, expert.severity.ERROR),
    frame_error = ProtoExpert.new("motorctl.frame_error.expert", "Frame error: answered E1",
        expert.group.MALFORMED, expert.severity.WARN),
    error_answer = ProtoExpert.new("motorctl.error_answer", "Error answer",
        expert.group.RESPONSE_CODE, expert.severity.NOTE),
    gap = ProtoExpert.new("motorctl.gap", "Partial frame dropped by the frame gap rule",
        expert.group.SEQUENCE, expert.severity.WARN),
    extra = ProtoExpert.new("motorctl.extra_answer", "Answer with no frame to answer",
        expert.group.SEQUENCE, expert.severity.WARN),
    lost = ProtoExpert.new("motorctl.lost.expert", "Byte runs left out (the recorder fell behind)",
        expert.group.SEQUENCE, expert.severity.WARN),
}
proto.experts = { e.checksum, e.frame_error, e.error_answer, e.gap, e.extra, e.lost }

-- preferences ---------------------------------------------------------------------------------

local checksum_enum = { { 1, "none", NONE } }
for i, crc in ipairs(CRCS) do
    checksum_enum[#checksum_enum + 1] = { i + 1, crc.name, i }
end
proto.prefs.checksum = Pref.enum("Checksum", SMBUS,
    "the link's checksum ([link] checksum; crc8 is CRC-8/SMBUS)", checksum_enum, false)
proto.prefs.crc_covers_ack = Pref.bool("Answer checksum covers R0", false,
    "[link] crc_covers_ack: the answer's checksum covers R0..R3, not R1..R3")
proto.prefs.strict_padding = Pref.bool("Strict padding", true,
    "[link] strict_padding: a frame with non-zero padding is an error (E1)")
proto.prefs.frame_gap_ms = Pref.uint("Frame gap (ms)", 10,
    "[link] frame_gap_ms: a partial frame is dropped after more than this much silence (0: never)")

-- CRC-8, as protocol/crc.py computes it --------------------------------------------------------

local function reflect8(v)
    local r = 0
    for _ = 1, 8 do
        r = bit.bor(bit.lshift(r, 1), bit.band(v, 1))
        v = bit.rshift(v, 1)
    end
    return bit.band(r, 0xFF)
end

local function crc8(params, s, first, last)
    local crc
    if params.refin then
        local rpoly = reflect8(params.poly)
        crc = reflect8(params.init)
        for i = first, last do
            crc = bit.bxor(crc, s:byte(i))
            for _ = 1, 8 do
                if bit.band(crc, 1) ~= 0 then
                    crc = bit.bxor(bit.rshift(crc, 1), rpoly)
                else
                    crc = bit.rshift(crc, 1)
                end
            end
        end
    else
        crc = params.init
        for i = first, last do
            crc = bit.bxor(crc, s:byte(i))
            for _ = 1, 8 do
                if bit.band(crc, 0x80) ~= 0 then
                    crc = bit.band(bit.bxor(bit.lshift(crc, 1), params.poly), 0xFF)
                else
                    crc = bit.band(bit.lshift(crc, 1), 0xFF)
                end
            end
        end
    end
    if params.refin ~= params.refout then
        crc = reflect8(crc)
    end
    return bit.bxor(crc, params.xorout)
end

local function crc_params()
    local choice = proto.prefs.checksum
    if choice == NONE then
        return nil
    end
    return CRCS[choice]
end

-- decoding (pure: a frame's bytes as a Lua string in, a table out) --------------------------

local function decode_command(s)
    local d = { code = s:byte(1), fields = {} }
    local params = crc_params()
    if params ~= nil then
        d.expected = crc8(params, s, 1, FRAME_LEN - 1)
        if s:byte(FRAME_LEN) ~= d.expected then
            d.error = "checksum"
            d.error_text = string.format("checksum 0x%02X, expected 0x%02X", s:byte(FRAME_LEN), d.expected)
        end
    end
    local layout = LAYOUT[d.code]
    if layout == nil then
        if d.error == nil then
            d.error = "unknown"
            d.error_text = string.format("unknown command code 0x%02X", d.code)
        end
        return d
    end
    local pos = 2
    for _, item in ipairs(layout) do
        local name, kind = item[1], item[2]
        local size = SIZE[kind]
        local v
        if size == 1 then
            v = s:byte(pos)
        elseif size == 2 then
            v = s:byte(pos) * 256 + s:byte(pos + 1)
        else
            v = (s:byte(pos) * 256 + s:byte(pos + 1)) * 256 + s:byte(pos + 2)
            if v >= 0x800000 then
                v = v - 0x1000000
            end
        end
        d.fields[#d.fields + 1] = { name = name, kind = kind, value = v, offset = pos - 1, size = size }
        pos = pos + size
    end
    d.padding_offset, d.padding_size = pos - 1, FRAME_LEN - pos
    if d.error == nil and proto.prefs.strict_padding then
        for i = pos, FRAME_LEN - 1 do
            if s:byte(i) ~= 0 then
                d.error = "padding"
                d.error_text = "non-zero padding in " .. COMMANDS[d.code] .. " frame"
                break
            end
        end
    end
    if d.error == nil then
        d.name = COMMANDS[d.code]
    end
    return d
end

local function field_text(fd)
    local v = fd.value
    if fd.kind == "dir" then
        return v ~= 0 and "up" or "down"
    elseif fd.kind == "dcdir" then
        return v ~= 0 and "forward" or "reverse"
    elseif fd.kind == "bool" or fd.kind == "level" then
        return v ~= 0 and "true" or "false"
    end
    return tostring(v)
end

local function describe(d)
    local parts = {}
    for _, fd in ipairs(d.fields) do
        parts[#parts + 1] = (SHORT[fd.name] or fd.name) .. "=" .. field_text(fd)
    end
    return d.name .. "(" .. table.concat(parts, ", ") .. ")"
end

local function decode_answer(s, cmd)
    local a = { r0 = s:byte(1), ack = s:byte(1) ~= 0 }
    local params = crc_params()
    if params ~= nil then
        if proto.prefs.crc_covers_ack then
            a.expected = crc8(params, s, 1, 4)
        else
            a.expected = crc8(params, s, 2, 4)
        end
        if s:byte(5) ~= a.expected then
            a.bad = string.format("response checksum 0x%02X, expected 0x%02X", s:byte(5), a.expected)
            return a
        end
    end
    local r1, r2, r3 = s:byte(2), s:byte(3), s:byte(4)
    local code = cmd and cmd.name and cmd.code or nil
    if not a.ack then
        a.error_code = r1
        a.text = ERROR_TEXT[r1] or string.format("error 0x%02x (unknown code)", r1)
    elseif code == 0x03 then
        a.ready = r1 ~= 0 and 1 or 0
        a.text = r1 ~= 0 and "ready" or "busy"
    elseif code == 0x06 then
        local v = (r1 * 256 + r2) * 256 + r3
        if v >= 0x800000 then
            v = v - 0x1000000
        end
        a.position = v
        a.text = "pos=" .. v
    elseif code == 0x08 then
        a.value = r1 ~= 0 and 1 or 0
        a.text = r1 ~= 0 and "high" or "low"
    elseif code == 0x0C then
        a.waypoint = r1
        a.text = "waypoint " .. r1
    elseif r1 == 0 and r2 == 0 and r3 == 0 then
        a.text = "ok"
    else
        a.text = string.format("ok, payload %02x %02x %02x", r1, r2, r3)
    end
    return a
end

-- the conversation: state per interface, results per packet -------------------------------

local f_time = Field.new("frame.time_epoch")
local f_interface = Field.new("frame.interface_id")
local ok_drop, f_drop = pcall(Field.new, "frame.drop_count")

local links = {} -- interface id -> the framer's and the pairing's state
local results = {} -- packet number -> the items it carries

function proto.init()
    links = {}
    results = {}
end

local function link_of(id)
    local l = links[id]
    if l == nil then
        l = { pending = "", out = "", waiting = {}, next_answer = 1, frames = 0 }
        -- waiting[k]: frame k until it is answered; answers pair in order (next_answer)
        links[id] = l
    end
    return l
end

local function ns_between(a, b) -- b - a in ns, exact (seconds and nanoseconds apart)
    return (b.secs - a.secs) * 1000000000 + (b.nsecs - a.nsecs)
end

local function hex(s)
    return (s:gsub(".", function(c)
        return string.format("%02x", c:byte())
    end))
end

-- first pass: what this run carries, in order
local function analyse(pinfo, data, inbound)
    local now = f_time().value
    local iface = f_interface()
    local l = link_of(iface and iface.value or 0)
    local items = {}
    if ok_drop then
        local drop = f_drop()
        if drop and drop.value and tonumber(tostring(drop.value)) ~= 0 then
            items[#items + 1] = { kind = "lost", count = drop.value }
        end
    end
    if inbound then
        local gap_ns = proto.prefs.frame_gap_ms * 1000000
        if #l.pending > 0 and l.last_in ~= nil and gap_ns > 0 and ns_between(l.last_in, now) > gap_ns then
            items[#items + 1] = { kind = "gap", data = l.pending,
                silence_ms = ns_between(l.last_in, now) / 1e6 }
            l.pending = ""
        end
        l.last_in = now
        local before = #l.pending
        local buf = l.pending .. data
        local n = math.floor(#buf / FRAME_LEN)
        for i = 0, n - 1 do
            local s = buf:sub(i * FRAME_LEN + 1, (i + 1) * FRAME_LEN)
            l.frames = l.frames + 1
            local d = decode_command(s)
            local item = { kind = d.name and "command" or "bad_frame", data = s, d = d, frame = l.frames,
                packet = pinfo.number, time = now }
            if i * FRAME_LEN - before >= 0 then
                item.offset = i * FRAME_LEN - before
            end
            items[#items + 1] = item
            l.waiting[l.frames] = item -- frame numbers count from 1: frame k waits at k
        end
        l.pending = buf:sub(n * FRAME_LEN + 1)
    else
        local before = #l.out
        local buf = l.out .. data
        local n = math.floor(#buf / RESPONSE_LEN)
        for i = 0, n - 1 do
            local s = buf:sub(i * RESPONSE_LEN + 1, (i + 1) * RESPONSE_LEN)
            local target = l.waiting[l.next_answer]
            local item = { data = s, packet = pinfo.number }
            if i * RESPONSE_LEN - before >= 0 then
                item.offset = i * RESPONSE_LEN - before
            end
            if target == nil then
                item.kind = "extra_answer"
            else
                l.waiting[l.next_answer] = nil
                l.next_answer = l.next_answer + 1
                item.target = target
                item.rtt = now - target.time
                target.answer_packet = pinfo.number
                item.a = decode_answer(s, target.d)
                item.kind = item.a.bad and "bad_answer" or "answer"
            end
            items[#items + 1] = item
        end
        l.out = buf:sub(n * RESPONSE_LEN + 1)
    end
    return items
end

-- drawing -------------------------------------------------------------------------------------

local function bytes_tvb(tvb, item, what)
    if item.offset ~= nil then
        return tvb:range(item.offset, #item.data)
    end
    -- a frame cut across runs: its bytes as a tab of their own
    return ByteArray.new(hex(item.data)):tvb(what):range(0, #item.data)
end

local FIELD_OF = {
    motor = f.motor, position = f.position, speed = f.speed, acc = f.acc, dec = f.dec,
    pin = f.pin, value = f.value, output = f.output, hard = f.hard, timeout_ms = f.timeout_ms,
    time_ms = f.time_ms, hiz = f.hiz, waypoint = f.waypoint, direction = f.direction,
}

local function draw_command(tree, range, item, pinfo)
    local d = item.d
    local label = item.kind == "command" and ("#" .. item.frame .. " " .. describe(d))
        or string.format("#%d frame error (%s): %s; E1 expected", item.frame, d.error, d.error_text)
    local t = tree:add(proto, range, "Command frame " .. label)
    t:add(f.kind, item.kind):set_generated()
    t:add(f.frame, item.frame):set_generated()
    t:add(f.code, range:range(0, 1))
    if d.name then
        t:add(f.command, range:range(0, 1), d.name)
        for _, fd in ipairs(d.fields) do
            local r = range:range(fd.offset, fd.size)
            if fd.kind == "dir" or fd.kind == "dcdir" then
                t:add(f.direction, r, field_text(fd))
            elseif fd.kind == "bool" or fd.kind == "level" then
                t:add(FIELD_OF[fd.name], r, fd.value ~= 0 and 1 or 0)
            elseif fd.kind == "s24" then
                t:add(FIELD_OF[fd.name], r, fd.value)
            else
                t:add(FIELD_OF[fd.name], r)
            end
        end
        if d.padding_size > 0 then
            t:add(f.padding, range:range(d.padding_offset, d.padding_size))
        end
    else
        t:add(f.frame_error, range, d.error)
        t:add_proto_expert_info(e.frame_error, d.error_text)
    end
    local ck = t:add(f.checksum, range:range(FRAME_LEN - 1, 1))
    if d.expected == nil then
        t:add(f.checksum_status, 2):set_generated()
    elseif d.expected == item.data:byte(FRAME_LEN) then
        t:add(f.checksum_status, 1):set_generated()
    else
        t:add(f.checksum_status, 0):set_generated()
        t:add(f.checksum_expected, d.expected):set_generated()
        ck:add_proto_expert_info(e.checksum, d.error_text)
    end
    if item.answer_packet ~= nil then
        t:add(f.response_in, item.answer_packet):set_generated()
    end
    return label
end

local function draw_answer(tree, range, item)
    local target, a = item.target, item.a
    local cmd = target.d
    local label
    if item.kind == "bad_answer" then
        label = "#" .. target.frame .. " bad answer: " .. a.bad
    else
        label = "#" .. target.frame .. " " .. a.text
    end
    local t = tree:add(proto, range, "Answer " .. label)
    t:add(f.kind, item.kind):set_generated()
    t:add(f.frame, target.frame):set_generated()
    if cmd.name then
        t:add(f.command, cmd.name):set_generated()
        t:add(f.code, cmd.code):set_generated()
        for _, fd in ipairs(cmd.fields) do
            if fd.name == "motor" or fd.name == "pin" then
                t:add(FIELD_OF[fd.name], fd.value):set_generated()
            end
        end
    end
    t:add(f.ack, range:range(0, 1))
    if item.kind == "answer" then
        t:add(f.answer, range:range(1, 3), a.text)
        if a.error_code ~= nil then
            t:add(f.error_code, range:range(1, 1))
            if ERRORS[a.error_code] then
                t:add(f.error_name, range:range(1, 1), ERRORS[a.error_code])
            else
                t:add(f.error_name, range:range(1, 1), "unknown error code")
            end
            t:add_proto_expert_info(e.error_answer, a.text)
        elseif a.ready ~= nil then
            t:add(f.ready, range:range(1, 1), a.ready)
        elseif a.position ~= nil then
            t:add(f.position, range:range(1, 3), a.position)
        elseif a.value ~= nil then
            t:add(f.value, range:range(1, 1), a.value)
        elseif a.waypoint ~= nil then
            t:add(f.waypoint, range:range(1, 1))
        else
            t:add(f.payload, range:range(1, 3))
        end
    else
        t:add(f.payload, range:range(1, 3))
    end
    local ck = t:add(f.checksum, range:range(4, 1))
    if a.expected == nil then
        t:add(f.checksum_status, 2):set_generated()
    elseif a.bad == nil then
        t:add(f.checksum_status, 1):set_generated()
    else
        t:add(f.checksum_status, 0):set_generated()
        t:add(f.checksum_expected, a.expected):set_generated()
        ck:add_proto_expert_info(e.checksum, a.bad)
    end
    t:add(f.request_in, target.packet):set_generated()
    t:add(f.rtt, item.rtt):set_generated()
    return label
end

function proto.dissector(tvb, pinfo, tree)
    pinfo.cols.protocol = "MOTORCTL"
    local items = results[pinfo.number]
    local inbound = pinfo.p2p_dir == DIR_RECV
    if pinfo.p2p_dir ~= DIR_RECV and pinfo.p2p_dir ~= DIR_SENT then
        tree:add(proto, tvb(), "motorctl byte run of unknown direction (no epb_flags)")
        pinfo.cols.info = "byte run of unknown direction"
        return tvb:len()
    end
    if items == nil then
        items = analyse(pinfo, tvb:len() > 0 and tvb:raw(0, tvb:len()) or "", inbound)
        results[pinfo.number] = items
    end
    local texts = {}
    local top = tree
    for _, item in ipairs(items) do
        if item.kind == "lost" then
            local t = top:add(proto, tvb(0, 0), "Byte runs left out before this one: " .. tostring(item.count))
            t:add(f.kind, "lost"):set_generated()
            t:add(f.lost, item.count):set_generated()
            t:add_proto_expert_info(e.lost)
            texts[#texts + 1] = tostring(item.count) .. " byte runs left out"
        elseif item.kind == "gap" then
            local r = bytes_tvb(tvb, item, "Partial frame")
            local text = string.format("partial frame dropped: %d of %d bytes, then %.1f ms of silence",
                #item.data, FRAME_LEN, item.silence_ms)
            local t = top:add(proto, r, text)
            t:add(f.kind, "gap"):set_generated()
            t:add(f.partial, r)
            t:add_proto_expert_info(e.gap)
            texts[#texts + 1] = text
        elseif item.kind == "command" or item.kind == "bad_frame" then
            local r = bytes_tvb(tvb, item, "Command frame #" .. item.frame)
            texts[#texts + 1] = draw_command(top, r, item, pinfo)
        elseif item.kind == "extra_answer" then
            local r = bytes_tvb(tvb, item, "Answer")
            local t = top:add(proto, r, "Answer with no frame to answer")
            t:add(f.kind, "extra_answer"):set_generated()
            t:add(f.ack, r:range(0, 1))
            t:add(f.payload, r:range(1, 3))
            t:add(f.checksum, r:range(4, 1))
            t:add_proto_expert_info(e.extra)
            texts[#texts + 1] = "answer with no frame to answer"
        else
            local r = bytes_tvb(tvb, item, "Answer to #" .. item.target.frame)
            texts[#texts + 1] = draw_answer(top, r, item)
        end
    end
    if #texts == 0 then
        tree:add(proto, tvb(), inbound and "Part of a command frame" or "Part of an answer")
        texts[1] = inbound and "part of a command frame" or "part of an answer"
    end
    pinfo.cols.info = table.concat(texts, "; ")
    return tvb:len()
end

DissectorTable.get("wtap_encap"):add(wtap_encaps.USER0, proto)
