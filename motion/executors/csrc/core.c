/* The compiled step core's rules: motion/executors/step_core.py in C, function by function
 * (what drives it, a virtual clock or the real clock's loop, is drive.c's).
 *
 * THE HOT LOOP, as step_core.py is: read that module's rules at its top; they hold here.
 * One owner (the thread that runs it), no locks, no allocation per step (a re-plan's cut
 * may grow its motor's list, never a step), no I/O but the lines' and the pipes'. Its
 * input is the shared block's rings (rings.c), read when a motor needs its next segment;
 * its output the block's cells (positions, levels, counters, per-motor figures, the
 * lateness histogram) and the event ring, each cell one aligned 8-byte store.
 *
 * Per step: pick the motors due now (their due times kept current, one pass over them);
 * a motor later than its slide_after slides the rest of its schedule by its lateness, or
 * stops (TIMING_LOST) where the lag it caused, in full steps, is one a real motor may not
 * survive; raise the STEP lines of every due motor in one call per GPIO request,
 * account while they are high, lower them after the pulse width, read end-stop edges,
 * look at the end stop ahead of each motor that stepped (and, in a plan that watches for
 * it, whether the end stop behind has released: RELEASED); a segment taken while the end
 * stop ahead of it is active already makes no step (ENDSTOP, "already active"). A line that
 * fails is a FAULT of the motors concerned, a record that is not whole or not sane a FAULT
 * of its motor (every motor for a stop record whose motor is unknown); the loop never dies
 * of either.
 *
 * Time: integer ns of CLOCK_MONOTONIC (Python's time.perf_counter_ns, the kernel's edge
 * timestamps), or a virtual clock that only the caller moves (tests). */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "stepcore.h"

#define SEG_BYTES (SEG_FIELDS * 8 + 8)
#define STOP_BYTES (STOP_FIELDS * 8 + 8)

int64_t core_mono(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * TICKS_PER_S + ts.tv_nsec;
}

int64_t core_now(struct core *c) { return c->virt ? c->vnow : core_mono(); }

void core_spin_until(struct core *c, int64_t t) {
    if (c->virt) {
        if (t > c->vnow)
            c->vnow = t;
        return;
    }
    while (core_mono() < t)
        ;
}

/* ---------------------------------------------------------------- reports */

static void emit_at(struct core *c, int kind, int m, int64_t gen, int64_t pos, int64_t t,
                    int64_t dir, double speed, const char *text, int64_t mark) {
    uint8_t rec[EVENT_BYTES];
    int64_t f[8] = {0, kind, m, gen, pos, t, dir, mark};
    memcpy(rec, f, sizeof f);
    memcpy(rec + sizeof f, &speed, 8);
    memset(rec + sizeof f + 8, 0, TEXT_LEN);
    if (text != NULL) {
        size_t n = strlen(text);
        memcpy(rec + sizeof f + 8, text, n < TEXT_LEN ? n : TEXT_LEN);
    }
    ring_put(&c->events, rec); /* full: the report is lost, as the Python core's */
    if (c->event_fd >= 0) {
        ssize_t w = write(c->event_fd, "e", 1); /* EAGAIN: a byte is there already */
        (void)w;
    }
}

static void emit(struct core *c, int kind, int m, int64_t gen, int64_t pos, int64_t t,
                 int64_t dir, double speed, const char *text) {
    emit_at(c, kind, m, gen, pos, t, dir, speed, text, 0);
}

static double speed_of(const struct motor *mo, int64_t planned) {
    int64_t gap = planned - mo->prev_t;
    return gap > 0 && gap < TICKS_PER_S ? (double)TICKS_PER_S / (double)gap : 0.0;
}

/* ---------------------------------------------------------------- the planner's requests */

static void unload(struct motor *mo) {
    mo->next_t = mo->due_t = NEVER;
    mo->left = 0;
}

static void drop(struct core *c, int m) {
    struct motor *mo = &c->m[m];
    if (mo->next_t != NEVER && mo->gen <= mo->stopped_gen)
        unload(mo);
    uint8_t buf[SEG_BYTES];
    char why[160];
    /* whole, sane records of an older plan only: a bad one is left for load() to report */
    while (ring_peek(&mo->ring, buf, core_now(c), INT64_MAX) == RING_WHOLE) {
        int64_t f[SEG_FIELDS];
        memcpy(f, buf, sizeof f);
        if (segment_problem(f, why, sizeof why) != NULL || f[6] > mo->stopped_gen)
            break;
        ring_take(&mo->ring);
        CELL_ADD(&c->counters[C_DROPPED], 1);
    }
}

void core_halt(struct core *c, int m) {
    c->m[m].stopped_gen = BLOCKED;
    drop(c, m);
}

/* the motors' FAULT: a line failed (io), or a record was bad */
static void fault(struct core *c, const int *motors, int n, const char *text) {
    for (int i = 0; i < n; i++) {
        int m = motors[i];
        struct motor *mo = &c->m[m];
        int64_t gen = mo->gen;
        double speed = mo->next_t == NEVER ? 0.0 : speed_of(mo, mo->next_t);
        core_halt(c, m);
        emit(c, EV_FAULT, m, gen, c->positions[m], core_now(c), mo->dir, speed, text);
    }
}

static void io_fault(struct core *c, const int *motors, int n) {
    char text[300];
    CELL_ADD(&c->counters[C_IO_ERRORS], 1);
    snprintf(text, sizeof text, "hardware error: %s", c->err);
    fault(c, motors, n, text);
}

/* a bad record: the fault of its motor (m >= 0) or, a stop's motor unknown, every motor */
static void bad_record(struct core *c, int m, const char *which, const char *problem) {
    char text[300];
    CELL_ADD(&c->counters[C_BAD_RECORDS], 1);
    snprintf(text, sizeof text, "bad %s record in the executor's ring: %s", which, problem);
    if (m >= 0) {
        fault(c, &m, 1, text);
        return;
    }
    fault(c, c->all, c->n, text);
}

static void torn_for(struct core *c, char *buf, size_t n) {
    snprintf(buf, n, "not whole after %.0f ms (CRC-32 or sequence number wrong)",
             (double)c->bad_after / 1e6);
}

static void lost(struct core *c, int m, int64_t now, const char *text, int64_t planned,
                 int have_planned) {
    struct motor *mo = &c->m[m];
    int64_t gen = mo->gen;
    double speed = speed_of(mo, have_planned ? planned : mo->next_t);
    core_halt(c, m);
    CELL_ADD(&c->counters[C_TIMING_LOST], 1);
    emit(c, EV_TIMING_LOST, m, gen, c->positions[m], now, mo->dir, speed, text);
}

static int load(struct core *c, int m);

/* before a segment's first step (step_core.py's _on_end_ahead): the end stop ahead in
 * direction d is active already (debounced), the motor stands on it: stopped there without a
 * step toward it, ENDSTOP as for a hit with the text ENDSTOP_ALREADY_ACTIVE; 1: stopped. A
 * new plan reads the edges first (at rest they were read only before the last wait). */
static int on_end_ahead(struct core *c, int m, int64_t gen, int d) {
    struct motor *mo = &c->m[m];
    int line = mo->end[d > 0 ? 1 : 0];
    if (line < 0)
        return 0;
    if (gen != mo->gen) {
        core_edges(c);
        if (mo->stopped_gen == BLOCKED)
            return 1; /* the read failed: faulted (every motor) */
    }
    if (!c->levels[line])
        return 0;
    int64_t since = c->since[line];
    if (core_now(c) - since < mo->debounce)
        return 0;
    core_halt(c, m);
    CELL_ADD(&c->counters[C_ENDSTOPS], 1);
    emit(c, EV_ENDSTOP, m, gen, c->positions[m], since > 0 ? since : 0, d, 0.0,
         ENDSTOP_ALREADY_ACTIVE);
    return 1;
}

static void cut(struct core *c, int m, int64_t gen, int64_t tick) {
    struct motor *mo = &c->m[m];
    if (mo->stopped_gen == BLOCKED)
        return; /* stopped on our own account: everything is dropped until the answer */
    if (mo->ncuts == mo->cap_cuts) { /* a re-plan, not a step: the one allocation */
        int cap = mo->cap_cuts ? 2 * mo->cap_cuts : 16;
        struct cut *grown = realloc(mo->cuts, (size_t)cap * sizeof *grown);
        if (grown == NULL) {
            snprintf(c->err, sizeof c->err, "out of memory for the re-plans of motor %d", m);
            io_fault(c, &m, 1);
            return;
        }
        mo->cuts = grown;
        mo->cap_cuts = cap;
    }
    mo->cuts[mo->ncuts].gen = gen;
    mo->cuts[mo->ncuts].tick = tick;
    mo->ncuts++;
    if (mo->next_t != NEVER && mo->gen <= gen && mo->seg_first >= tick) {
        if (mo->left < mo->seg_count) { /* it began already: the re-plan came late */
            int64_t now = core_now(c);
            int64_t late = now - tick - c->mcells[m * N_MOTOR_CELLS + M_SHIFT];
            char text[120];
            snprintf(text, sizeof text, "re-plan came %.0f us late", (double)late / 1000.0);
            lost(c, m, now, text, 0, 0);
            return;
        }
        unload(mo);
    }
    if (mo->next_t == NEVER)
        load(c, m); /* drops what the cut removed (as it will for what comes later) */
}

static int cut_off(const struct motor *mo, int64_t gen, int64_t first) {
    for (int i = 0; i < mo->ncuts; i++)
        if (gen <= mo->cuts[i].gen && first >= mo->cuts[i].tick)
            return 1;
    return 0;
}

static void apply_stops(struct core *c) {
    uint8_t buf[STOP_BYTES];
    char why[160];
    for (;;) {
        enum ring_got got = ring_peek(&c->stops, buf, core_now(c), c->bad_after);
        if (got == RING_EMPTY || got == RING_TORN)
            return;
        if (got == RING_BAD) { /* taken already; whose it was is unknown */
            torn_for(c, why, sizeof why);
            bad_record(c, -1, "stop", why);
            continue;
        }
        int64_t f[STOP_FIELDS];
        memcpy(f, buf, sizeof f);
        ring_take(&c->stops);
        const char *problem = stop_problem(f, c->n, why, sizeof why);
        if (problem != NULL) {
            bad_record(c, f[1] >= 0 && f[1] < c->n ? (int)f[1] : -1, "stop", problem);
            continue;
        }
        int m = (int)f[1];
        int64_t gen = f[2], tick = f[3];
        if (tick >= 0) {
            cut(c, m, gen, tick);
            continue;
        }
        struct motor *mo = &c->m[m];
        mo->stopped_gen = gen;
        mo->ncuts = 0; /* every cut so far was of an older plan: all dropped now */
        drop(c, m);
        emit(c, EV_STOPPED, m, gen, c->positions[m], core_now(c), 0, 0.0, NULL);
    }
}

static void set_dir(struct core *c, int m, int d) {
    struct motor *mo = &c->m[m];
    int up = d > 0;
    if (mo->out_dir != up) { /* StepOutputs.set_direction */
        int64_t hold = mo->last_fall + mo->dir_hold;
        if (core_now(c) < hold)
            core_spin_until(c, hold);
        mo->out_dir = -1; /* unknown until the write succeeded */
        if (lines_dir(c, m, up != mo->invert_dir) < 0) {
            io_fault(c, &m, 1);
            return;
        }
        mo->out_dir = up;
        mo->ready_at = core_now(c) + mo->dir_setup;
    }
    mo->dir = d;
    mo->ready = mo->ready_at;
}

/* the motor's next segment; 1 when one is loaded */
static int load(struct core *c, int m) {
    struct motor *mo = &c->m[m];
    uint8_t buf[SEG_BYTES];
    char why[160];
    for (;;) {
        enum ring_got got = ring_peek(&mo->ring, buf, core_now(c), c->bad_after);
        if (got == RING_EMPTY || got == RING_TORN)
            return 0;
        if (got == RING_BAD) {
            torn_for(c, why, sizeof why);
            bad_record(c, m, "step segment", why);
            continue;
        }
        if (mo->stopped_gen == BLOCKED && ring_pending(&c->stops)) {
            apply_stops(c); /* the answer may have come with these segments */
            if (mo->next_t != NEVER)
                return 1; /* a cut in that answer loaded it already */
            continue;
        }
        int64_t f[SEG_FIELDS];
        memcpy(f, buf, sizeof f);
        ring_take(&mo->ring);
        const char *problem = segment_problem(f, why, sizeof why);
        if (problem != NULL) {
            bad_record(c, m, "step segment", problem);
            continue;
        }
        int64_t first = f[1], gen = f[6];
        if (gen <= mo->stopped_gen || (mo->ncuts && cut_off(mo, gen, first))) {
            CELL_ADD(&c->counters[C_DROPPED], 1);
            continue;
        }
        if (mo->ncuts && mo->cuts[0].gen < gen) { /* no segment of those plans comes any more */
            int keep = 0;
            for (int i = 0; i < mo->ncuts; i++)
                if (mo->cuts[i].gen >= gen)
                    mo->cuts[keep++] = mo->cuts[i];
            mo->ncuts = keep;
        }
        if (f[3] <= 0) { /* a marker: the plan before it is complete */
            if (f[7] & SEG_LAST)
                emit(c, EV_DONE, m, gen, c->positions[m], core_now(c), 0, 0.0, NULL);
            continue;
        }
        if ((f[7] & SEG_WATCH) && on_end_ahead(c, m, gen, (int)f[5]))
            return 0; /* the end stop ahead is active already: no step toward it */
        int64_t at = first + c->mcells[m * N_MOTOR_CELLS + M_SHIFT];
        mo->next_t = at;
        mo->iv = f[2];
        mo->add = f[4];
        mo->left = mo->seg_count = f[3];
        mo->seg_first = first; /* plan ticks, as the planner's cuts */
        if (gen != mo->gen)
            mo->rel_at = NEVER; /* a new plan sees the release for itself */
        mo->gen = gen;
        mo->last = (f[7] & SEG_LAST) != 0;
        mo->watch = (f[7] & SEG_WATCH) != 0;
        mo->release = (f[7] & SEG_RELEASE) != 0;
        if (f[5] != mo->dir) {
            set_dir(c, m, (int)f[5]);
            if (mo->next_t == NEVER)
                return 0; /* the DIR write failed: faulted */
        }
        int64_t earliest = mo->last_edge + mo->min_iv;
        int64_t d = at >= earliest ? at : earliest;
        mo->due_t = d >= mo->ready ? d : mo->ready;
        return 1;
    }
}

/* new work: stops, then the idle motors' next segments (every record announced is read
 * again, so a torn one is taken once whole, or found bad) */
void core_take(struct core *c) {
    if (c->stops.cells[1] < __atomic_load_n(&c->stops.cells[0], __ATOMIC_ACQUIRE))
        apply_stops(c);
    for (int m = 0; m < c->n; m++) {
        struct motor *mo = &c->m[m];
        if (mo->next_t == NEVER &&
            mo->ring.cells[1] < __atomic_load_n(&mo->ring.cells[0], __ATOMIC_ACQUIRE))
            load(c, m);
    }
}

/* a line's level and since when (its last edge) */
void core_apply_edge(struct core *c, int line, int active, int64_t t) {
    CELL_SET(&c->levels[line], active);
    c->since[line] = t;
}

void core_edges(struct core *c) {
    if (lines_edges(c) < 0)
        io_fault(c, c->all, c->n);
}

void core_refill(struct core *c) {
    core_take(c);
    core_edges(c);
}

int64_t core_deadline(const struct core *c) {
    int64_t d = NEVER;
    for (int m = 0; m < c->n; m++)
        if (c->m[m].due_t < d)
            d = c->m[m].due_t;
    return d;
}

/* ---------------------------------------------------------------- one edge */

static void record_ns(struct core *c, int64_t ns) {
    int64_t *l = c->latency;
    CELL_ADD(&l[L_COUNT], 1);
    if (ns > l[L_MAX])
        CELL_SET(&l[L_MAX], ns);
    if (ns > c->late_thr)
        CELL_ADD(&l[L_LATE], 1);
    if (ns > 0)
        CELL_ADD(&l[L_SUM], ns);
    int64_t us = ns >= 0 ? ns / 1000 : 0;
    if (us > L_BINS)
        us = L_BINS;
    CELL_ADD(&l[L_BIN0 + us], 1);
    CELL_ADD(&l[L_BLOCK0 + (us >> L_BLOCK_SHIFT)], 1);
}

/* 1: stopped at the active end stop ahead, debounced */
static int check_endstop(struct core *c, int m, int line) {
    struct motor *mo = &c->m[m];
    int64_t since = c->since[line];
    if (core_now(c) - since < mo->debounce)
        return 0;
    int64_t gen = mo->gen;
    core_halt(c, m);
    CELL_ADD(&c->counters[C_ENDSTOPS], 1);
    emit(c, EV_ENDSTOP, m, gen, c->positions[m], since > 0 ? since : 0, mo->dir, 0.0, NULL);
    return 1;
}

/* motor m stepped away from the end stop behind it (homing's back-off): stop once that has
 * been inactive for the debounce time; RELEASED says where it released (the first position
 * seen off it; an unwired line is off it at the first step) */
static void check_release(struct core *c, int m) {
    struct motor *mo = &c->m[m];
    int line = mo->end[mo->dir > 0 ? 0 : 1];
    int64_t since = 0;
    if (line >= 0) {
        if (c->levels[line]) {
            mo->rel_at = NEVER; /* still on it, or on it again (a bounce) */
            return;
        }
        since = c->since[line];
    }
    if (mo->rel_at == NEVER || mo->rel_since != since) { /* released by a new edge */
        mo->rel_at = c->positions[m];
        mo->rel_since = since;
    }
    if (core_now(c) - since < mo->debounce)
        return;
    int64_t gen = mo->gen;
    core_halt(c, m);
    emit_at(c, EV_RELEASED, m, gen, c->positions[m], since > 0 ? since : 0, -mo->dir, 0.0,
            NULL, mo->rel_at);
}

/* motor m's step is late: slide the rest of its schedule, or stop it where the lag is one a
 * real motor may not survive; 0: stopped */
static int late(struct core *c, int m, int64_t now) {
    struct motor *mo = &c->m[m];
    int64_t planned = mo->next_t;
    int64_t lat = now - planned;
    int64_t gap = planned - mo->prev_t; /* the interval this step ends: the motor's rate */
    int moving = gap > 0 && gap < TICKS_PER_S;
    int64_t *cells = &c->mcells[m * N_MOTOR_CELLS];
    double lag = moving ? (double)lat / (double)gap / (double)mo->microsteps : 0.0;
    if (lat > cells[M_WORST_LATE])
        CELL_SET(&cells[M_WORST_LATE], lat);
    double ulag_f = lag * LAG_UNIT;
    int64_t ulag = ulag_f >= 9.2e18 ? INT64_MAX : (int64_t)ulag_f;
    if (ulag > cells[M_WORST_LAG])
        CELL_SET(&cells[M_WORST_LAG], ulag);
    if (mo->lag_faults && moving && gap < mo->start_gap &&
        (double)lat > (double)gap * mo->lag_k) {
        CELL_ADD(&cells[M_LAG_FAULTS], 1);
        char text[300];
        snprintf(text, sizeof text,
                 "step %.0f us late at %.0f step/s: lag %.3f full steps > max_lag_full_steps "
                 "%g (%lld microsteps, start_speed %g step/s)",
                 (double)lat / 1000.0, speed_of(mo, planned), lag, mo->max_lag,
                 (long long)mo->microsteps, mo->start_speed);
        lost(c, m, now, text, planned, 1);
        return 0;
    }
    CELL_ADD(&cells[M_SHIFT], lat);
    CELL_ADD(&cells[M_ABSORBED], 1);
    mo->slid = lat;
    mo->next_t = now; /* (and the steps after it keep their intervals from here) */
    return 1;
}

/* the motors due at now into c->due (their count): due, or planned within coalesce of now
 * with nothing else holding it back (it shares this pulse); *slid: one of them slid */
static int pick_due(struct core *c, int64_t now, int *slid) {
    int64_t soon = now + c->coalesce;
    int ndue = 0;
    for (int m = 0; m < c->n; m++) {
        struct motor *mo = &c->m[m];
        int64_t d = mo->due_t;
        if (d <= now || (d <= soon && d == mo->next_t)) {
            if (now - mo->next_t > mo->slide_after) {
                if (!late(c, m, now))
                    continue; /* stopped: a real motor may have lost steps */
                *slid = 1;
            }
            c->due[ndue++] = m;
        }
    }
    return ndue;
}

/* while the STEP lines are high: lateness, positions, next steps (a segment's end into
 * c->done, *ndone), counters; the pulse width to keep */
static int64_t account(struct core *c, int ndue, int slid, int64_t rise, int *ndone) {
    int64_t width = 0;
    int64_t *counters = c->counters;
    for (int i = 0; i < ndue; i++) {
        int m = c->due[i];
        struct motor *mo = &c->m[m];
        int64_t planned = mo->next_t;
        if (slid && mo->slid) { /* judged against the schedule before it slid */
            record_ns(c, rise - planned + mo->slid);
            mo->slid = 0;
        } else {
            record_ns(c, rise - planned);
        }
        int64_t gap = rise - mo->last_edge;
        if (gap < GAP_WINDOW) {
            int64_t g = counters[C_MIN_GAP];
            if (gap < g || !g)
                CELL_SET(&counters[C_MIN_GAP], gap);
        }
        CELL_ADD(&c->positions[m], mo->dir);
        mo->prev_t = planned;
        mo->last_edge = rise;
        if (mo->width > width)
            width = mo->width;
        int64_t left = --mo->left;
        if (left > 0) {
            int64_t nt = planned + mo->iv;
            mo->next_t = nt;
            mo->iv += mo->add;
            int64_t earliest = rise + mo->min_iv;
            mo->due_t = nt >= earliest ? nt : earliest;
        } else {
            mo->next_t = mo->due_t = NEVER;
            c->done[(*ndone)++] = m;
        }
    }
    CELL_ADD(&counters[C_STEPS], ndue);
    return width;
}

/* each motor that stepped: the end stop ahead, and the one behind where it is watched for
 * its release */
static void look_at_ends(struct core *c, int ndue) {
    for (int i = 0; i < ndue; i++) {
        int m = c->due[i];
        struct motor *mo = &c->m[m];
        if (mo->watch) {
            int line = mo->end[mo->dir > 0 ? 1 : 0];
            if (line >= 0 && c->levels[line] && check_endstop(c, m, line))
                continue;
        }
        if (mo->release)
            check_release(c, m);
    }
}

/* each motor whose segment the step ended: DONE after a plan's last, its next one */
static void go_on(struct core *c, int ndone, int64_t rise) {
    for (int i = 0; i < ndone; i++) {
        int m = c->done[i];
        struct motor *mo = &c->m[m];
        if (mo->stopped_gen == BLOCKED)
            continue; /* stopped on its own account: nothing more until the answer */
        if (mo->last) /* before the next segment (a marker reports its own DONE) */
            emit(c, EV_DONE, m, mo->gen, c->positions[m], rise, 0, 0.0, NULL);
        load(c, m);
    }
}

void core_step(struct core *c, int64_t now) {
    int slid = 0, ndone = 0;
    int ndue = pick_due(c, now, &slid);
    if (ndue == 0)
        return;
    if (lines_steps(c, c->due, ndue, 1) < 0) {
        io_fault(c, c->due, ndue);
        return;
    }
    /* the edge happened by now (StepOutputs.rise): the accounting while the lines are high */
    int64_t rise = core_now(c);
    int64_t width = account(c, ndue, slid, rise, &ndone);
    if (!c->virt) /* StepOutputs.fall: not before the pulse width (a virtual clock stays) */
        core_spin_until(c, rise + width);
    int failed = lines_steps(c, c->due, ndue, 0) < 0;
    int64_t fall = core_now(c);
    if (failed) {
        io_fault(c, c->due, ndue);
        return;
    }
    for (int i = 0; i < ndue; i++)
        c->m[c->due[i]].last_fall = fall;
    /* the end stops after this step, in its direction and generation, before a motor whose
     * segment it ended reports DONE or goes on: a last step onto the switch is an end stop
     * hit, not a move done */
    core_edges(c);
    look_at_ends(c, ndue);
    go_on(c, ndone, rise);
}
