/* The compiled step core's lines, as Python hands them over (methods of the Core type,
 * module.c): gpio(), the GPIO character-device line requests of the gpiod backends (their
 * descriptors, uAPI versions, offsets; lines_gpio.c drives them); sim(), the mock's shared
 * cells of simulated mechanics (lines_sim.c); sim_error(), a write error injected into a
 * simulated line; level(), an input line's level before the start. Each is checked in full
 * here, once: the loop checks nothing twice. Owner: the thread that made the core. */
#include <poll.h>
#include <stdlib.h>
#include <string.h>

#include "module.h"

PyObject *Core_level(CoreObject *self, PyObject *args) {
    int line, active;
    if (!PyArg_ParseTuple(args, "ip", &line, &active) || core_usable(self, 0) < 0)
        return NULL;
    if (line < 0 || line >= self->c.nlines)
        return PyErr_Format(PyExc_ValueError, "no input line %d", line);
    CELL_SET(&self->c.levels[line], active);
    Py_RETURN_NONE;
}

static int pair(PyObject *item, int *a, int *b) {
    return PyArg_ParseTuple(item, "ii", a, b) ? 0 : -1;
}

PyObject *Core_gpio(CoreObject *self, PyObject *args) {
    PyObject *outs, *steps, *dirs, *ins;
    Py_buffer lows;
    if (!PyArg_ParseTuple(args, "O!O!O!O!y*", &PyList_Type, &outs, &PyList_Type, &steps,
                          &PyList_Type, &dirs, &PyList_Type, &ins, &lows))
        return NULL;
    struct core *c = &self->c;
    struct gpio *g = &c->gpio;
    PyObject *result = NULL;
    if (core_usable(self, 0) < 0)
        goto done;
    if (c->kind != LINES_NONE) {
        PyErr_SetString(PyExc_RuntimeError, "the lines are given once");
        goto done;
    }
    Py_ssize_t nout = PyList_GET_SIZE(outs), nin = PyList_GET_SIZE(ins);
    if (PyList_GET_SIZE(steps) != c->n || PyList_GET_SIZE(dirs) != c->n ||
        lows.len != c->nlines || nout < 1 || nout > 64 || nin > 4096) {
        PyErr_SetString(PyExc_ValueError, "gpio: one STEP and DIR per motor, an active_low "
                        "per input line, 1..64 output requests");
        goto done;
    }
    g->out = calloc((size_t)nout, sizeof *g->out);
    g->mask = calloc((size_t)nout, sizeof *g->mask);
    g->in = calloc((size_t)(nin ? nin : 1), sizeof *g->in);
    g->pfd = calloc((size_t)(nin ? nin : 1), sizeof(struct pollfd));
    g->active_low = calloc((size_t)(c->nlines ? c->nlines : 1), 1);
    if (!g->out || !g->mask || !g->in || !g->pfd || !g->active_low) {
        PyErr_NoMemory();
        goto done;
    }
    g->nout = (int)nout;
    g->nin = (int)nin;
    memcpy(g->active_low, lows.buf, (size_t)lows.len);
    for (Py_ssize_t r = 0; r < nout; r++) {
        struct gpio_out *o = &g->out[r];
        Py_buffer lv;
        if (!PyArg_ParseTuple(PyList_GET_ITEM(outs, r), "iiy*", &o->fd, &o->uapi, &lv))
            goto done;
        int ok = (o->uapi == 1 || o->uapi == 2) && lv.len >= 1 && lv.len <= 64 && o->fd >= 0;
        o->nlines = (int)lv.len;
        for (Py_ssize_t i = 0; ok && i < lv.len; i++)
            o->level[i] = ((uint8_t *)lv.buf)[i] != 0;
        PyBuffer_Release(&lv);
        if (!ok) {
            PyErr_SetString(PyExc_ValueError, "gpio: an output request needs a descriptor, "
                            "uAPI 1 or 2 and 1..64 lines");
            goto done;
        }
    }
    for (int m = 0; m < c->n; m++) {
        struct motor *mo = &c->m[m];
        if (pair(PyList_GET_ITEM(steps, m), &mo->step_req, &mo->step_bit) < 0 ||
            pair(PyList_GET_ITEM(dirs, m), &mo->dir_req, &mo->dir_bit) < 0)
            goto done;
        if (mo->step_req < 0 || mo->step_req >= nout || mo->dir_req < 0 || mo->dir_req >= nout ||
            mo->step_bit < 0 || mo->step_bit >= g->out[mo->step_req].nlines ||
            mo->dir_bit < 0 || mo->dir_bit >= g->out[mo->dir_req].nlines) {
            PyErr_Format(PyExc_ValueError, "gpio: motor %d's lines are not in its requests", m);
            goto done;
        }
        self->configured[m] |= 2;
    }
    struct pollfd *pfd = g->pfd;
    for (Py_ssize_t r = 0; r < nin; r++) {
        struct gpio_in *in = &g->in[r];
        PyObject *lines;
        if (!PyArg_ParseTuple(PyList_GET_ITEM(ins, r), "iiO!", &in->fd, &in->uapi, &PyList_Type,
                              &lines))
            goto done;
        Py_ssize_t k = PyList_GET_SIZE(lines);
        if ((in->uapi != 1 && in->uapi != 2) || in->fd < 0 || k < 1 || k > 64 ||
            (in->uapi == 1 && k != 1)) {
            PyErr_SetString(PyExc_ValueError, "gpio: an input request needs a descriptor, uAPI "
                            "1 (one line) or 2 (1..64 lines)");
            goto done;
        }
        in->nlines = (int)k;
        for (Py_ssize_t i = 0; i < k; i++) {
            if (pair(PyList_GET_ITEM(lines, i), &in->offset[i], &in->line[i]) < 0)
                goto done;
            if (in->line[i] < 0 || in->line[i] >= c->nlines) {
                PyErr_Format(PyExc_ValueError, "gpio: no input line %d", in->line[i]);
                goto done;
            }
        }
        pfd[r].fd = in->fd;
        pfd[r].events = POLLIN;
    }
    c->kind = LINES_GPIO;
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&lows);
    if (result == NULL && c->kind != LINES_GPIO)
        gpio_free(g);
    return result;
}

static int int64_list(PyObject *seq, Py_ssize_t n, int64_t *out) {
    if (!PyList_Check(seq) || PyList_GET_SIZE(seq) != n)
        return core_fail(PyExc_ValueError, "sim: a list with one value per axis or motor");
    for (Py_ssize_t i = 0; i < n; i++) {
        long long v = PyLong_AsLongLong(PyList_GET_ITEM(seq, i));
        if (v == -1 && PyErr_Occurred())
            return -1;
        out[i] = v;
    }
    return 0;
}

PyObject *Core_sim(CoreObject *self, PyObject *args) {
    PyObject *cells, *emin, *emax, *switches, *axis_of;
    long long tl_max;
    if (!PyArg_ParseTuple(args, "OOOOOL", &cells, &emin, &emax, &switches, &axis_of, &tl_max))
        return NULL;
    struct core *c = &self->c;
    struct sim *s = &c->sim;
    if (core_usable(self, 0) < 0)
        return NULL;
    if (c->kind != LINES_NONE)
        return PyErr_Format(PyExc_RuntimeError, "the lines are given once");
    if (c->nlines % 2 || c->nlines < 2)
        return PyErr_Format(PyExc_ValueError, "sim: two input lines per axis");
    int naxes = c->nlines / 2;
    if (PyObject_GetBuffer(cells, &self->cells, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    self->have_cells = 1;
    if (self->cells.len < (Py_ssize_t)naxes * AX_FIELDS * 8 || (uintptr_t)self->cells.buf % 8)
        return PyErr_Format(PyExc_ValueError, "sim: the cells hold fewer than %d axes", naxes);
    s->cells = self->cells.buf;
    s->naxes = naxes;
    s->tl_max = tl_max < 0 ? -1 : tl_max;
    s->emin = calloc((size_t)naxes, 8);
    s->emax = calloc((size_t)naxes, 8);
    s->switches = calloc((size_t)naxes, 8);
    s->seen_gen = calloc((size_t)naxes, 8);
    s->seen_pos = calloc((size_t)naxes, 8);
    s->level = calloc((size_t)c->nlines, 1);
    s->step_err = calloc((size_t)naxes, sizeof(char *));
    s->dir_err = calloc((size_t)naxes, sizeof(char *));
    int64_t *axes = calloc((size_t)c->n, 8);
    int bad = !s->emin || !s->emax || !s->switches || !s->seen_gen || !s->seen_pos ||
              !s->level || !s->step_err || !s->dir_err || !axes;
    if (bad)
        PyErr_NoMemory();
    bad = bad || int64_list(emin, naxes, s->emin) < 0 || int64_list(emax, naxes, s->emax) < 0 ||
          int64_list(switches, naxes, s->switches) < 0 || int64_list(axis_of, c->n, axes) < 0;
    for (int m = 0; !bad && m < c->n; m++) {
        if (axes[m] < 0 || axes[m] >= naxes) {
            PyErr_Format(PyExc_ValueError, "sim: motor %d has no axis %lld", m,
                         (long long)axes[m]);
            bad = 1;
            break;
        }
        c->m[m].axis = (int)axes[m];
        self->configured[m] |= 2;
    }
    free(axes);
    if (bad) {
        sim_free(s);
        return NULL;
    }
    for (int a = 0; a < naxes; a++) {
        s->seen_gen[a] = s->cells[AX_FIELDS * a + AX_GEN];
        s->seen_pos[a] = s->cells[AX_FIELDS * a + AX_POS];
    }
    for (int line = 0; line < c->nlines; line++) {
        s->level[line] = (int8_t)sim_sense(s, line);
        CELL_SET(&c->levels[line], s->level[line]);
    }
    c->kind = LINES_SIM;
    Py_RETURN_NONE;
}

PyObject *Core_sim_error(CoreObject *self, PyObject *args) {
    const char *kind, *text;
    int axis;
    if (!PyArg_ParseTuple(args, "siz", &kind, &axis, &text) || core_usable(self, -1) < 0)
        return NULL;
    struct sim *s = &self->c.sim;
    if (self->c.kind != LINES_SIM || axis < 0 || axis >= s->naxes ||
        (strcmp(kind, "step") && strcmp(kind, "dir")))
        return PyErr_Format(PyExc_ValueError, "sim: no %s line of axis %d", kind, axis);
    char **slot = strcmp(kind, "step") ? &s->dir_err[axis] : &s->step_err[axis];
    free(*slot);
    *slot = NULL;
    if (text != NULL && (*slot = strdup(text)) == NULL)
        return PyErr_NoMemory();
    s->errors = 0;
    for (int a = 0; a < s->naxes; a++)
        s->errors |= s->step_err[a] != NULL;
    Py_RETURN_NONE;
}
