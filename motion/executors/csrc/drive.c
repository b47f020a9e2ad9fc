/* What drives the compiled step core (core.c): a virtual clock's advance and run_until
 * (tests), the real clock's loop and its waits (the executor process's main thread), halts,
 * and the lines by kind (lines_gpio.c, lines_sim.c). step_core.py's drivers (``advance``,
 * ``run``) in C; the rules they apply per step are core.c's.
 *
 * The same owner as core.c: the one thread that runs the core. */
#define _GNU_SOURCE
#include <poll.h>
#include <time.h>
#include <unistd.h>

#include "stepcore.h"

/* ---------------------------------------------------------------- drivers */

void core_advance(struct core *c, int64_t now) {
    if (now > c->vnow)
        c->vnow = now;
    core_refill(c);
    core_step(c, now);
    core_refill(c);
}

void core_run_until(struct core *c, int64_t until) {
    core_refill(c);
    int64_t d;
    while ((d = core_deadline(c)) != NEVER && d <= until) {
        if (d > c->vnow)
            c->vnow = d; /* never backwards: after a stall, "now" is later */
        core_advance(c, c->vnow);
    }
    if (until > c->vnow)
        c->vnow = until;
}

void core_halt_all(struct core *c) {
    for (int m = 0; m < c->n; m++)
        core_halt(c, m);
}

static void wait_for(struct core *c, int64_t timeout) {
    if (c->parent > 0 && getppid() != c->parent) { /* the daemon is gone */
        CELL_SET(&c->header[H_RUN], 0);
        return;
    }
    struct pollfd p = {.fd = c->wake_fd, .events = POLLIN, .revents = 0};
    struct timespec ts = {.tv_sec = timeout / TICKS_PER_S, .tv_nsec = timeout % TICKS_PER_S};
    if (ppoll(&p, 1, &ts, NULL) > 0) {
        char buf[4096];
        if (read(c->wake_fd, buf, sizeof buf) == 0) /* the daemon's end is closed: gone */
            CELL_SET(&c->header[H_RUN], 0);
    }
}

/* the real clock: the loop, until the header's run cell is 0 (the daemon's close) or the
 * daemon is gone; end-stop edges are read after each step and before each wait */
void core_run(struct core *c) {
    int64_t *run = &c->header[H_RUN];
    while (__atomic_load_n(run, __ATOMIC_ACQUIRE)) {
        CELL_ADD(&c->counters[C_PROGRESS], 1);
        core_take(c);
        int64_t d = core_deadline(c);
        if (d == NEVER) {
            core_edges(c);
            wait_for(c, c->idle);
            continue;
        }
        int64_t now = core_mono();
        if (d - now > c->spin) {
            core_edges(c);
            int64_t t = d - c->spin - now;
            wait_for(c, t < c->idle ? t : c->idle);
            continue;
        }
        while (now < d && !ring_pending(&c->stops))
            now = core_mono();
        if (ring_pending(&c->stops))
            continue;
        core_step(c, now);
    }
}

/* ---------------------------------------------------------------- lines */

int lines_dir(struct core *c, int m, int level) {
    return c->kind == LINES_GPIO ? gpio_dir(c, m, level) : sim_dir(c, m, level);
}

int lines_steps(struct core *c, const int *motors, int n, int level) {
    return c->kind == LINES_GPIO ? gpio_steps(c, motors, n, level)
                                 : sim_steps(c, motors, n, level);
}

int lines_edges(struct core *c) {
    if (c->kind == LINES_GPIO)
        return gpio_edges(c);
    sim_edges(c);
    return 0;
}
