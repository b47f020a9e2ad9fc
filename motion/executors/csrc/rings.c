/* The shared block's rings as the compiled core reads and writes them.
 *
 * The layout and the rules are motion/executors/process/rings.py's (class Ring): a ring is
 * three cells (head, tail, retries) and its slots; a slot is the record (its first field the
 * sequence number) followed by the CRC-32 (zlib's) of the record and 4 zero bytes, so the
 * CRC-32 of a whole slot whose check matches is one constant. The consumer copies a slot once
 * and takes it only when that copy's CRC and sequence number are right; anything else is "not
 * written yet", counted as a retry and read again later. A record still not whole after
 * ``bad_after`` ns and two reads or more is bad (a store takes nanoseconds to show, never that
 * long): it is taken, so the ring moves on, and the caller faults its motor. Fields of a whole
 * record are checked before use (segment_problem, stop_problem: the rules of the functions
 * of those names in motion/executors/process/rings.py): no record, however made, can make the
 * core overflow, run away or step without its spacing. */
#include <stdio.h>
#include <string.h>

#include "stepcore.h"

static uint32_t table[256];
static uint32_t residue;

static void crc_init(void) {
    if (table[1])
        return;
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i;
        for (int k = 0; k < 8; k++)
            c = c & 1 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        table[i] = c;
    }
    static const uint8_t zeros[8] = {0};
    residue = crc32_of(zeros, sizeof zeros, 0);
}

uint32_t crc32_of(const uint8_t *p, size_t n, uint32_t crc) {
    crc = ~crc;
    while (n--)
        crc = table[(crc ^ *p++) & 0xFF] ^ (crc >> 8);
    return ~crc;
}

void ring_init(struct ring *r, uint8_t *at, size_t rec, int64_t cap) {
    crc_init();
    r->cells = (int64_t *)(void *)at;
    r->slots = at + 3 * 8;
    r->rec = rec;
    r->slot = rec + 8;
    r->cap = cap;
    r->fail_tail = -1;
    r->fail_since = 0;
    r->fail_reads = 0;
}

int64_t rec_field(const uint8_t *rec, int i) {
    int64_t v;
    memcpy(&v, rec + 8 * i, 8);
    return v;
}

enum ring_got ring_peek(struct ring *r, uint8_t *out, int64_t now, int64_t bad_after) {
    int64_t head = __atomic_load_n(&r->cells[0], __ATOMIC_ACQUIRE);
    int64_t tail = r->cells[1];
    if (tail >= head)
        return RING_EMPTY;
    const uint8_t *at = r->slots + (size_t)(tail % r->cap) * r->slot;
    memcpy(out, at, r->slot); /* one copy: what is checked is what is used */
    if (crc32_of(out, r->slot, 0) == residue && rec_field(out, 0) == tail + 1) {
        r->fail_tail = -1;
        return RING_WHOLE;
    }
    CELL_ADD(&r->cells[2], 1);
    if (r->fail_tail != tail) {
        r->fail_tail = tail;
        r->fail_since = now;
        r->fail_reads = 1;
        return RING_TORN;
    }
    r->fail_reads++;
    if (r->fail_reads < 2 || now - r->fail_since < bad_after)
        return RING_TORN;
    r->fail_tail = -1;
    ring_take(r);
    return RING_BAD;
}

void ring_take(struct ring *r) {
    /* after the check on every byte loaded: the producer cannot reuse the slot before */
    __atomic_store_n(&r->cells[1], r->cells[1] + 1, __ATOMIC_RELEASE);
}

int ring_pending(const struct ring *r) {
    int64_t tail = r->cells[1];
    return tail < __atomic_load_n(&r->cells[0], __ATOMIC_RELAXED) && tail != r->fail_tail;
}

int ring_put(struct ring *r, uint8_t *rec) {
    int64_t head = r->cells[0];
    if (head - __atomic_load_n(&r->cells[1], __ATOMIC_ACQUIRE) >= r->cap)
        return 0;
    int64_t seq = head + 1;
    memcpy(rec, &seq, 8);
    uint8_t *at = r->slots + (size_t)(head % r->cap) * r->slot;
    memcpy(at, rec, r->rec);
    uint32_t crc = crc32_of(rec, r->rec, 0);
    uint8_t check[8] = {(uint8_t)crc, (uint8_t)(crc >> 8), (uint8_t)(crc >> 16),
                        (uint8_t)(crc >> 24), 0, 0, 0, 0};
    memcpy(at + r->rec, check, 8);
    __atomic_store_n(&r->cells[0], seq, __ATOMIC_RELEASE);
    return 1;
}

#define LIM_GEN (INT64_C(1) << 62)
#define LIM_TICK (INT64_C(1) << 59)
#define LIM_COUNT (INT64_C(1) << 24)
#define LIM_IV (INT64_C(1) << 34)

const char *segment_problem(const int64_t *f, char *buf, size_t n) {
    int64_t first = f[1], interval = f[2], count = f[3], add = f[4], dir = f[5], gen = f[6],
            flags = f[7];
    if (gen < 0 || gen >= LIM_GEN)
        snprintf(buf, n, "generation %lld", (long long)gen);
    else if (flags & ~(int64_t)(SEG_LAST | SEG_WATCH | SEG_RELEASE))
        snprintf(buf, n, "flags %lld", (long long)flags);
    else if (count < 0 || count > LIM_COUNT)
        snprintf(buf, n, "count %lld", (long long)count);
    else if (count == 0)
        return NULL; /* a marker: nothing is timed by it */
    else if (dir != 1 && dir != -1)
        snprintf(buf, n, "direction %lld", (long long)dir);
    else if (first < 0 || first >= LIM_TICK)
        snprintf(buf, n, "first step at tick %lld", (long long)first);
    else if (interval < 0 || interval >= LIM_IV)
        snprintf(buf, n, "interval %lld", (long long)interval);
    else if (add <= -LIM_IV || add >= LIM_IV || (add < 0 ? -add : add) * count >= LIM_IV)
        snprintf(buf, n, "add %lld over %lld steps", (long long)add, (long long)count);
    else if (count >= 2 && interval + add * (count - 2) < 0)
        snprintf(buf, n, "intervals below 0 (interval %lld, add %lld, count %lld)",
                 (long long)interval, (long long)add, (long long)count);
    else
        return NULL;
    return buf;
}

const char *stop_problem(const int64_t *f, int64_t motors, char *buf, size_t n) {
    int64_t motor = f[1], gen = f[2], cut = f[3];
    if (motor < 0 || motor >= motors)
        snprintf(buf, n, "motor %lld", (long long)motor);
    else if (gen < 0 || gen >= LIM_GEN)
        snprintf(buf, n, "generation %lld", (long long)gen);
    else if (cut != -1 && (cut < 0 || cut >= LIM_TICK))
        snprintf(buf, n, "cut at tick %lld", (long long)cut);
    else
        return NULL;
    return buf;
}
