/* The compiled step core (motorctl.motion.executors._stepcore): what its files share.
 *
 * The same contract as motion/executors/step_core.py, the Python reference: step segments in
 * (from the shared block's rings), edges on lines, events, positions, levels, counters and the
 * lateness histogram out (the block's cells), the same slide, lag, spacing, DIR settle,
 * shared-pulse and end-stop rules. What each file holds:
 *
 *   core.c       the rules of the loop (mirrors step_core.py function by function)
 *   drive.c      what drives it: a virtual clock, the real clock's loop; the lines by kind
 *   rings.c      CRC-32, the rings' records (motion/executors/process/rings.py Ring), checks
 *   lines_gpio.c STEP/DIR writes and end-stop edge reads as GPIO character-device ioctls
 *   lines_sim.c  the mock backend's counterpart: the same timeline of edges, the same
 *                simulated mechanics (positions, end stops) in the same shared cells
 *   module.c     the Python type that builds a core and drives it (module.h: its object)
 *   module_lines.c  its methods that hand the core its lines (gpio(), sim())
 *
 * Owners: one thread runs a core (the executor process's main thread, or a test's on a
 * virtual clock); nothing here is shared between threads but the block's cells, which
 * other processes read as snapshots. No allocation per step, no locks, no I/O but the
 * lines' and the two wake-up pipes'. */
#ifndef MOTORCTL_STEPCORE_H
#define MOTORCTL_STEPCORE_H

#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "the shared block's records are little-endian (struct '<q'): a big-endian host needs byte swaps"
#endif

#define TICKS_PER_S INT64_C(1000000000)
#define NEVER (INT64_C(1) << 62)   /* no step pending */
#define BLOCKED (INT64_C(1) << 62) /* stopped_gen after the core stopped a motor itself */
#define GAP_WINDOW (TICKS_PER_S / 10)
#define TEXT_LEN 120 /* an event's text field */
/* an ENDSTOP's text when the end stop ahead was active before the first step (base.py's) */
#define ENDSTOP_ALREADY_ACTIVE "already active"

/* counters cells (core_cells.COUNTER_NAMES) */
enum { C_PROGRESS, C_STEPS, C_TIMING_LOST, C_IO_ERRORS, C_ENDSTOPS, C_DROPPED, C_MIN_GAP,
       C_BAD_RECORDS, N_COUNTERS };
/* per motor cells (core_cells.MOTOR_CELL_NAMES) */
enum { M_SHIFT, M_ABSORBED, M_WORST_LATE, M_WORST_LAG, M_LAG_FAULTS, N_MOTOR_CELLS };
#define LAG_UNIT 1000000.0
/* header cells (executor_process: _RUN, _READY, _PID, _CORE) */
enum { H_RUN = 0 };
/* latency cells (motion/latency.py) */
#define L_BINS 20000
#define L_BLOCK_SHIFT 6
#define L_COUNT 0
#define L_LATE 1
#define L_MAX 2
#define L_SUM 3 /* lateness summed, ns; early edges as 0 */
#define L_BIN0 4
#define L_BLOCK0 (L_BIN0 + L_BINS + 1)
#define L_BLOCKS ((L_BINS + 1 + (1 << L_BLOCK_SHIFT) - 1) >> L_BLOCK_SHIFT)
#define L_CELLS (L_BLOCK0 + L_BLOCKS)
/* event kinds (list(ExecEventKind)) */
enum { EV_DONE, EV_STOPPED, EV_ENDSTOP, EV_TIMING_LOST, EV_FAULT, EV_DIED, EV_RELEASED };
/* an event record: seq, kind, motor, gen, position, t, direction, mark; speed; text */
#define EVENT_BYTES (8 * 8 + 8 + TEXT_LEN)

/* One aligned 8-byte cell of the block, stored whole (single-copy atomic) for readers in
 * another process; only the core stores to its cells, so plain loads read them back. */
#define CELL_SET(p, v) __atomic_store_n((p), (int64_t)(v), __ATOMIC_RELAXED)
#define CELL_ADD(p, v) CELL_SET((p), *(p) + (v))

/* ------------------------------------------------------------------ rings.c */
#define SEG_FIELDS 8  /* seq, first, interval, count, add, direction, gen, flags */
#define STOP_FIELDS 4 /* seq, motor, gen, cut */
#define SEG_LAST 1
#define SEG_WATCH 2
#define SEG_RELEASE 4

struct ring {
    int64_t *cells; /* head (the producer's), tail, retries (the consumer's) */
    uint8_t *slots;
    int64_t cap;
    size_t rec;  /* record bytes (first field: the sequence number) */
    size_t slot; /* rec + CRC-32 + 4 zero bytes */
    /* the consumer's watch on a record announced but not (yet) whole */
    int64_t fail_tail, fail_since, fail_reads;
};

enum ring_got { RING_EMPTY, RING_TORN, RING_WHOLE, RING_BAD };

uint32_t crc32_of(const uint8_t *p, size_t n, uint32_t crc);
void ring_init(struct ring *r, uint8_t *at, size_t rec, int64_t cap);
/* the next record, copied into ``out`` (``slot`` bytes) and not taken: RING_WHOLE; RING_EMPTY;
 * RING_TORN (announced, not whole yet: counted as a retry, read again later); RING_BAD (torn
 * for ``bad_after`` ns over two reads or more: taken, so the ring moves on) */
enum ring_got ring_peek(struct ring *r, uint8_t *out, int64_t now, int64_t bad_after);
void ring_take(struct ring *r);
int ring_pending(const struct ring *r); /* a record announced that is not known torn */
int ring_put(struct ring *r, uint8_t *rec);  /* fills the sequence number; 0: full */
int64_t rec_field(const uint8_t *rec, int i);
/* what is wrong with a whole record's fields (NULL: nothing): the rules of
 * motion/executors/process/rings.py */
const char *segment_problem(const int64_t *f, char *buf, size_t n);
const char *stop_problem(const int64_t *f, int64_t motors, char *buf, size_t n);

/* ------------------------------------------------------------------ the core */
struct cut {
    int64_t gen, tick;
};

struct motor {
    /* limits (AxisLimits, in ticks) */
    int64_t min_iv, slide_after, start_gap, width, debounce, microsteps;
    double lag_k, max_lag, start_speed;
    int lag_faults;
    int end[2]; /* input line at the min, max side; -1: not wired */
    /* the segment being made */
    int64_t next_t, due_t, iv, add, left, seg_first, seg_count, gen, prev_t, last_edge;
    int64_t stopped_gen, ready, slid;
    int64_t rel_at, rel_since; /* where the end stop behind was seen released (NEVER: not) */
    int dir, last, watch, release;
    struct cut *cuts;
    int ncuts, cap_cuts;
    /* the outputs' own state (StepOutputs: direction, ready_at, last_fall) */
    int invert_dir, out_dir; /* out_dir: -1 unknown, 0 down, 1 up */
    int64_t dir_setup, dir_hold, ready_at, last_fall;
    struct ring ring;
    /* lines */
    int step_req, step_bit, dir_req, dir_bit; /* gpio: request, index in it */
    int axis;                                 /* sim: the world's axis */
};

struct gpio_out {
    int fd, uapi, nlines;
    uint8_t level[64]; /* v1 writes every line of a handle at once */
};

struct gpio_in {
    int fd, uapi, nlines;
    int offset[64], line[64];
};

struct gpio {
    struct gpio_out *out;
    int nout;
    struct gpio_in *in;
    int nin;
    void *pfd; /* struct pollfd[nin] */
    uint64_t *mask;
    int8_t *active_low; /* per input line */
};

struct tl_entry {
    int64_t t, call;
    int32_t kind, axis, value, pad;
};

/* a simulated axis' cells (hal/backends/mock/world.py's MockAxis) */
enum { AX_POS, AX_HEADING, AX_FMIN, AX_FMAX, AX_STALL, AX_GEN, AX_PUSHED, AX_FIELDS };

struct sim {
    int64_t *cells; /* per world axis: AX_FIELDS cells */
    int naxes;
    int64_t *emin, *emax, *switches, *seen_gen, *seen_pos;
    int8_t *level;     /* per line (2 per world axis): the sensed level */
    char **step_err;   /* per world axis: the injected error's text, or NULL */
    char **dir_err;
    int errors;        /* any injected */
    struct tl_entry *tl;
    int64_t tl_cap, tl_start, tl_len, tl_max; /* tl_max < 0: unbounded */
    int64_t call;
};

enum { LINES_NONE, LINES_GPIO, LINES_SIM };

struct core {
    int n, nlines;
    struct motor *m;
    int64_t *header, *counters, *positions, *levels, *latency, *mcells;
    struct ring stops, events;
    int64_t *since;
    int *due, *done, *all; /* the motors due at an edge, those it ended, every motor */
    int64_t late_thr, spin, coalesce, idle, bad_after;
    int virt;
    int64_t vnow;
    int wake_fd, event_fd;
    pid_t parent;
    int kind;
    struct gpio gpio;
    struct sim sim;
    int started;
    char err[256]; /* the last line error's text (HalIOError's message) */
};

int64_t core_mono(void);
int64_t core_now(struct core *c);
void core_spin_until(struct core *c, int64_t t);
void core_take(struct core *c);
void core_edges(struct core *c);
void core_step(struct core *c, int64_t now);
void core_halt(struct core *c, int m);
void core_refill(struct core *c);
int64_t core_deadline(const struct core *c);
void core_advance(struct core *c, int64_t now);
void core_run_until(struct core *c, int64_t until);
void core_run(struct core *c);
void core_halt_all(struct core *c);
void core_apply_edge(struct core *c, int line, int active, int64_t t);

/* lines: 0 done, -1 failed (c->err says why) */
int lines_dir(struct core *c, int m, int level);
int lines_steps(struct core *c, const int *motors, int n, int level);
int lines_edges(struct core *c);
int gpio_dir(struct core *c, int m, int level);
int gpio_steps(struct core *c, const int *motors, int n, int level);
int gpio_edges(struct core *c);
int sim_dir(struct core *c, int m, int level);
int sim_steps(struct core *c, const int *motors, int n, int level);
void sim_edges(struct core *c);
int sim_sense(const struct sim *s, int line);
void sim_free(struct sim *s);
void gpio_free(struct gpio *g);

#endif
