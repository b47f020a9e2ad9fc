/* GPIO lines for the compiled core: kernel GPIO character-device ioctls on the line requests
 * the gpiod backend opened (hal/backends/gpiod), handed over as their file descriptors and
 * the order of their lines (hal.interfaces.ChardevLines). No Python and no libgpiod per step.
 *
 * - Outputs (STEP, DIR, ENABLE of the motors on one chip: one request): uAPI v2
 *   GPIO_V2_LINE_SET_VALUES_IOCTL with a mask of the lines written, so the STEP lines of
 *   every due motor on a chip rise in one call; v1 GPIOHANDLE_SET_LINE_VALUES_IOCTL, which
 *   sets every line of the handle, with the levels of the others kept here (ENABLE as the
 *   backend set it, DIR as last written), as the backend's own v1 request does.
 * - End stops (edge-event requests): one poll() over them without waiting, then read() of
 *   the pending events of the ready ones: v2 struct gpio_v2_line_event (the line's offset
 *   in it), v1 struct gpioevent_data (one line per request). Their kernel timestamps are
 *   CLOCK_MONOTONIC, the core's clock.
 * A failing call is a HalIOError of the backend's wording (the core's FAULT text).
 *
 * Hardware edge code kept beside the core it is compiled into (one extension, called per
 * edge with no Python between), not under hal/backends/gpiod: the backend owns the lines and
 * what they are, this file only drives them (docs/timing.md, "The compiled step core"). */
#include <errno.h>
#include <linux/gpio.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include "stepcore.h"

static int set_lines(struct gpio_out *o, uint64_t mask, int level) {
    if (o->uapi == 2) {
        struct gpio_v2_line_values v = {.bits = level ? mask : 0, .mask = mask};
        return ioctl(o->fd, GPIO_V2_LINE_SET_VALUES_IOCTL, &v);
    }
    struct gpiohandle_data d;
    memset(&d, 0, sizeof d);
    for (int i = 0; i < o->nlines; i++) {
        if (mask >> i & 1)
            o->level[i] = (uint8_t)(level != 0);
        d.values[i] = o->level[i];
    }
    return ioctl(o->fd, GPIOHANDLE_SET_LINE_VALUES_IOCTL, &d);
}

int gpio_dir(struct core *c, int m, int level) {
    const struct motor *mo = &c->m[m];
    if (set_lines(&c->gpio.out[mo->dir_req], UINT64_C(1) << mo->dir_bit, level) < 0) {
        int e = errno;
        snprintf(c->err, sizeof c->err, "motor %d: DIR write failed: [Errno %d] %s", m, e,
                 strerror(e));
        return -1;
    }
    return 0;
}

int gpio_steps(struct core *c, const int *motors, int n, int level) {
    struct gpio *g = &c->gpio;
    for (int r = 0; r < g->nout; r++)
        g->mask[r] = 0;
    for (int i = 0; i < n; i++) {
        const struct motor *mo = &c->m[motors[i]];
        g->mask[mo->step_req] |= UINT64_C(1) << mo->step_bit;
    }
    for (int r = 0; r < g->nout; r++) {
        if (g->mask[r] == 0 || set_lines(&g->out[r], g->mask[r], level) == 0)
            continue;
        int e = errno, at = 0;
        at += snprintf(c->err + at, sizeof c->err - (size_t)at, "motors [");
        for (int i = 0; i < n && at < (int)sizeof c->err - 16; i++)
            at += snprintf(c->err + at, sizeof c->err - (size_t)at, i ? ", %d" : "%d", motors[i]);
        snprintf(c->err + at, sizeof c->err - (size_t)at,
                 "]: STEP write failed: [Errno %d] %s", e, strerror(e));
        return -1;
    }
    return 0;
}

static int edge_error(struct core *c, int e) {
    snprintf(c->err, sizeof c->err, "end stops: reading edge events failed: [Errno %d] %s", e,
             strerror(e));
    return -1;
}

static int read_events(struct core *c, const struct gpio_in *in) {
    if (in->uapi == 2) {
        struct gpio_v2_line_event ev[16];
        ssize_t got = read(in->fd, ev, sizeof ev);
        if (got < 0)
            return errno == EAGAIN || errno == EINTR ? 0 : edge_error(c, errno);
        for (size_t k = 0; k < (size_t)got / sizeof ev[0]; k++)
            for (int i = 0; i < in->nlines; i++)
                if ((uint32_t)in->offset[i] == ev[k].offset) {
                    int line = in->line[i];
                    int rising = ev[k].id == GPIO_V2_LINE_EVENT_RISING_EDGE;
                    core_apply_edge(c, line, rising != c->gpio.active_low[line],
                                    (int64_t)ev[k].timestamp_ns);
                }
        return 0;
    }
    struct gpioevent_data ev[16];
    ssize_t got = read(in->fd, ev, sizeof ev);
    if (got < 0)
        return errno == EAGAIN || errno == EINTR ? 0 : edge_error(c, errno);
    for (size_t k = 0; k < (size_t)got / sizeof ev[0]; k++) {
        int line = in->line[0];
        int rising = ev[k].id == GPIOEVENT_EVENT_RISING_EDGE;
        core_apply_edge(c, line, rising != c->gpio.active_low[line], (int64_t)ev[k].timestamp);
    }
    return 0;
}

int gpio_edges(struct core *c) {
    struct gpio *g = &c->gpio;
    if (g->nin == 0)
        return 0;
    struct pollfd *p = g->pfd;
    int ready = poll(p, (nfds_t)g->nin, 0);
    if (ready < 0)
        return errno == EINTR ? 0 : edge_error(c, errno);
    for (int r = 0; r < g->nin && ready > 0; r++) {
        if (p[r].revents == 0)
            continue;
        ready--;
        if (p[r].revents & (POLLERR | POLLNVAL))
            return edge_error(c, p[r].revents & POLLNVAL ? EBADF : EIO);
        if (read_events(c, &g->in[r]) < 0)
            return -1;
    }
    return 0;
}

void gpio_free(struct gpio *g) {
    free(g->out);
    free(g->in);
    free(g->pfd);
    free(g->mask);
    free(g->active_low);
    memset(g, 0, sizeof *g);
}
