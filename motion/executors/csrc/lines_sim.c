/* The mock backend's lines for the compiled core: hal/backends/mock/backend.py's
 * MockStepOutputs and MockEdgeInputs in C, on the same simulated mechanics.
 *
 * The mechanics are the mock world's cells (seven int64 per axis: position, heading, forced
 * min, forced max, forced stall, generation, pushed), in shared memory when the executor
 * runs in a process of its own, so the daemon's world sees every step. A STEP rise moves
 * each due motor's axis by one, unless that pushes it against a hard stop (the end stop's
 * position: the pulse is lost and the axis pushed, what the mock's driver reports as a
 * stall), and records a "step" event (the logical direction) in the timeline,
 * a DIR write records a "dir" event (the physical level) and sets the heading; a step
 * onto or off a simulated end stop is an edge at the step's time; an end stop forced by a
 * test, or a position set by hand, is seen at the next read, with that read's time. The
 * timeline is kept here (bounded as the world's) and handed to the world's Timeline by
 * the Python side (motion/executors/compiled_core.py), with the number of the rise call of
 * each step (which motors shared a pulse). Errors injected into the world's lines (inject_line_error)
 * come as texts per axis: a write to such a line fails as the mock's does.
 *
 * Kept beside the core it is compiled into, not under hal/backends/mock, as lines_gpio.c
 * (docs/timing.md, "The compiled step core"). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stepcore.h"

enum { F_UNSET, F_OFF, F_ON };
enum { TL_STEP, TL_DIR };

int sim_sense(const struct sim *s, int line) {
    int axis = line / 2, max = line % 2;
    const int64_t *a = s->cells + AX_FIELDS * axis;
    int64_t forced = a[max ? AX_FMAX : AX_FMIN];
    if (forced != F_UNSET)
        return forced == F_ON;
    if (!s->switches[axis])
        return 0;
    return max ? a[AX_POS] >= s->emax[axis] : a[AX_POS] <= s->emin[axis];
}

static void moved(struct core *c, int axis, int64_t t) {
    struct sim *s = &c->sim;
    const int64_t *a = s->cells + AX_FIELDS * axis;
    s->seen_gen[axis] = __atomic_load_n(&a[AX_GEN], __ATOMIC_RELAXED);
    s->seen_pos[axis] = __atomic_load_n(&a[AX_POS], __ATOMIC_RELAXED);
    for (int line = 2 * axis; line < 2 * axis + 2; line++) {
        int now = sim_sense(s, line);
        if (now != s->level[line]) {
            s->level[line] = (int8_t)now;
            core_apply_edge(c, line, now, t);
        }
    }
}

static void tl_push(struct sim *s, int64_t t, int kind, int axis, int value, int64_t call) {
    if (s->tl_max == 0)
        return;
    if (s->tl_max > 0 && s->tl_len == s->tl_max) { /* a bounded deque: the oldest goes */
        s->tl_start = (s->tl_start + 1) % s->tl_cap;
        s->tl_len--;
    }
    if (s->tl_len == s->tl_cap) { /* grows by doubling (the mock only; bounded by tl_max) */
        int64_t cap = s->tl_cap ? 2 * s->tl_cap : 1024;
        if (s->tl_max > 0 && cap > s->tl_max)
            cap = s->tl_max;
        struct tl_entry *grown = malloc((size_t)cap * sizeof *grown);
        if (grown == NULL)
            return; /* the record of a simulated edge is lost, nothing else */
        for (int64_t i = 0; i < s->tl_len; i++)
            grown[i] = s->tl[(s->tl_start + i) % s->tl_cap];
        free(s->tl);
        s->tl = grown;
        s->tl_cap = cap;
        s->tl_start = 0;
    }
    struct tl_entry *e = &s->tl[(s->tl_start + s->tl_len) % s->tl_cap];
    e->t = t;
    e->call = call;
    e->kind = kind;
    e->axis = axis;
    e->value = value;
    e->pad = 0;
    s->tl_len++;
}

int sim_dir(struct core *c, int m, int level) {
    struct sim *s = &c->sim;
    int axis = c->m[m].axis;
    if (s->dir_err[axis] != NULL) {
        snprintf(c->err, sizeof c->err, "%s", s->dir_err[axis]);
        return -1;
    }
    int up = level != c->m[m].invert_dir;
    CELL_SET(&s->cells[AX_FIELDS * axis + AX_HEADING], up ? 1 : 2);
    tl_push(s, core_now(c), TL_DIR, axis, level, 0);
    return 0;
}

int sim_steps(struct core *c, const int *motors, int n, int level) {
    struct sim *s = &c->sim;
    if (s->errors)
        for (int i = 0; i < n; i++) {
            const char *e = s->step_err[c->m[motors[i]].axis];
            if (e != NULL) {
                snprintf(c->err, sizeof c->err, "%s", e);
                return -1;
            }
        }
    if (!level)
        return 0;
    int64_t t = core_now(c), call = ++s->call;
    for (int i = 0; i < n; i++) {
        const struct motor *mo = &c->m[motors[i]];
        tl_push(s, t, TL_STEP, mo->axis, mo->out_dir == 1, call);
    }
    for (int i = 0; i < n; i++) {
        const struct motor *mo = &c->m[motors[i]];
        int64_t *a = &s->cells[AX_FIELDS * mo->axis];
        int up = mo->out_dir == 1;
        if (up ? a[AX_POS] >= s->emax[mo->axis] : a[AX_POS] <= s->emin[mo->axis]) {
            CELL_SET(&a[AX_PUSHED], 1); /* against the hard stop: the pulse is lost */
        } else {
            CELL_SET(&a[AX_POS], a[AX_POS] + (up ? 1 : -1));
            CELL_SET(&a[AX_PUSHED], 0);
        }
        moved(c, mo->axis, t);
    }
    return 0;
}

void sim_edges(struct core *c) {
    struct sim *s = &c->sim;
    for (int axis = 0; axis < s->naxes; axis++) {
        const int64_t *a = s->cells + AX_FIELDS * axis;
        if (__atomic_load_n(&a[AX_GEN], __ATOMIC_RELAXED) != s->seen_gen[axis] ||
            __atomic_load_n(&a[AX_POS], __ATOMIC_RELAXED) != s->seen_pos[axis])
            moved(c, axis, core_now(c));
    }
}

void sim_free(struct sim *s) {
    for (int i = 0; i < s->naxes; i++) {
        if (s->step_err != NULL)
            free(s->step_err[i]);
        if (s->dir_err != NULL)
            free(s->dir_err[i]);
    }
    free(s->step_err);
    free(s->dir_err);
    free(s->emin);
    free(s->emax);
    free(s->switches);
    free(s->seen_gen);
    free(s->seen_pos);
    free(s->level);
    free(s->tl);
    memset(s, 0, sizeof *s);
}
