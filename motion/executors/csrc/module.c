/* motorctl.motion.executors._stepcore: the compiled step core as a Python type.
 *
 * motion/executors/compiled_core.py builds one (Core(...), then motor(), the lines: gpio() or
 * sim(), then start()) over the shared block of motion/executors/process/rings.py and drives
 * it: run() is the executor process's whole loop, with the GIL released, until the block's run
 * cell is 0 or the daemon is gone; refill(), deadline(), advance() and run_until() are the
 * virtual-clock entry (tests, the benchmark's cost). Everything is checked when given (offsets
 * inside the block, lines inside their requests): the loop itself checks nothing twice. Owner:
 * the thread that made it. The lines' set-up (gpio(), sim(), sim_error(), level()):
 * module_lines.c. */
#include <stdlib.h>

#include "module.h"

int core_fail(PyObject *type, const char *msg) {
    PyErr_SetString(type, msg);
    return -1;
}

int core_usable(CoreObject *self, int started) {
    if (self->closed)
        return core_fail(PyExc_ValueError, "the step core is closed");
    if (started >= 0 && self->c.started != started)
        return core_fail(PyExc_RuntimeError,
                         started ? "the step core is not started" : "the step core is started");
    return 0;
}

static int region(CoreObject *self, Py_ssize_t off, Py_ssize_t size, const char *what) {
    if (off < 0 || off % 8 || size < 0 || off > self->block.len - size) {
        PyErr_Format(PyExc_ValueError, "%s at %zd (%zd bytes) is not inside the %zd-byte block "
                     "or not 8-byte aligned", what, off, size, self->block.len);
        return -1;
    }
    return 0;
}

static int64_t *cells_at(CoreObject *self, Py_ssize_t off) {
    return (int64_t *)(void *)((uint8_t *)self->block.buf + off);
}

static void release(CoreObject *self) {
    struct core *c = &self->c;
    if (c->m != NULL)
        for (int m = 0; m < c->n; m++)
            free(c->m[m].cuts);
    free(c->m);
    free(c->since);
    free(c->due);
    free(c->done);
    free(c->all);
    free(self->configured);
    gpio_free(&c->gpio);
    sim_free(&c->sim);
    c->m = NULL;
    c->since = NULL;
    c->due = c->done = c->all = NULL;
    self->configured = NULL;
    if (self->have_block)
        PyBuffer_Release(&self->block);
    if (self->have_cells)
        PyBuffer_Release(&self->cells);
    self->have_block = self->have_cells = 0;
    self->closed = 1;
}

static void Core_dealloc(CoreObject *self) {
    release(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Core_init(CoreObject *self, PyObject *args, PyObject *kw) {
    static char *names[] = {"block", "offsets", "seg_rings", "caps", "motors", "lines",
                            "timing", NULL};
    PyObject *block, *seg_rings;
    Py_ssize_t o[8], caps[3], timing[5];
    int motors, lines;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "O(nnnnnnnn)O(nnn)ii(nnnnn)", names, &block,
                                     &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                                     &seg_rings, &caps[0], &caps[1], &caps[2], &motors, &lines,
                                     &timing[0], &timing[1], &timing[2], &timing[3],
                                     &timing[4]))
        return -1;
    if (self->have_block || self->closed)
        return core_fail(PyExc_RuntimeError, "a step core is made once");
    if (motors < 1 || motors > 1024 || lines < 0 || lines > 4096)
        return core_fail(PyExc_ValueError, "motors must be 1..1024, lines 0..4096");
    for (int i = 0; i < 3; i++)
        if (caps[i] < 1 || caps[i] > (1 << 24))
            return core_fail(PyExc_ValueError, "ring capacities must be 1..2**24");
    if (PyObject_GetBuffer(block, &self->block, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) < 0)
        return -1;
    self->have_block = 1;
    if ((uintptr_t)self->block.buf % 8)
        return core_fail(PyExc_ValueError, "the block is not 8-byte aligned");
    PyObject *rings = PySequence_Fast(seg_rings, "seg_rings must be a sequence");
    if (rings == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(rings) != motors) {
        Py_DECREF(rings);
        return core_fail(PyExc_ValueError, "one segment ring per motor");
    }
    struct core *c = &self->c;
    const size_t seg_rec = SEG_FIELDS * 8, stop_rec = STOP_FIELDS * 8, ev_rec = EVENT_BYTES;
    int bad = region(self, o[0], 8 * 8, "the header") ||
              region(self, o[1], N_COUNTERS * 8, "the counters") ||
              region(self, o[2], (Py_ssize_t)motors * 8, "the positions") ||
              region(self, o[3], (Py_ssize_t)(lines > 0 ? lines : 1) * 8, "the levels") ||
              region(self, o[4], L_CELLS * 8, "the latency cells") ||
              region(self, o[5], (Py_ssize_t)motors * N_MOTOR_CELLS * 8, "the motor cells") ||
              region(self, o[6], 24 + caps[1] * (Py_ssize_t)(stop_rec + 8), "the stop ring") ||
              region(self, o[7], 24 + caps[2] * (Py_ssize_t)(ev_rec + 8), "the event ring");
    c->n = motors;
    c->nlines = lines;
    c->m = calloc((size_t)motors, sizeof *c->m);
    c->since = calloc((size_t)(lines > 0 ? lines : 1), sizeof *c->since);
    c->due = calloc((size_t)motors, sizeof *c->due);
    c->done = calloc((size_t)motors, sizeof *c->done);
    c->all = calloc((size_t)motors, sizeof *c->all);
    self->configured = calloc((size_t)motors, sizeof *self->configured);
    if (!bad && (!c->m || !c->since || !c->due || !c->done || !c->all || !self->configured)) {
        PyErr_NoMemory();
        bad = 1;
    }
    for (int m = 0; !bad && m < motors; m++) {
        Py_ssize_t off = PyLong_AsSsize_t(PySequence_Fast_GET_ITEM(rings, m));
        if (off == -1 && PyErr_Occurred()) {
            bad = 1;
            break;
        }
        bad = region(self, off, 24 + caps[0] * (Py_ssize_t)(seg_rec + 8), "a segment ring");
        if (!bad)
            ring_init(&c->m[m].ring, (uint8_t *)self->block.buf + off, seg_rec, caps[0]);
    }
    Py_DECREF(rings);
    if (bad)
        return -1;
    c->header = cells_at(self, o[0]);
    c->counters = cells_at(self, o[1]);
    c->positions = cells_at(self, o[2]);
    c->levels = cells_at(self, o[3]);
    c->latency = cells_at(self, o[4]);
    c->mcells = cells_at(self, o[5]);
    ring_init(&c->stops, (uint8_t *)self->block.buf + o[6], stop_rec, caps[1]);
    ring_init(&c->events, (uint8_t *)self->block.buf + o[7], ev_rec, caps[2]);
    c->late_thr = timing[0];
    c->spin = timing[1];
    c->coalesce = timing[2];
    c->idle = timing[3];
    c->bad_after = timing[4];
    c->wake_fd = c->event_fd = -1;
    for (int m = 0; m < motors; m++) {
        struct motor *mo = &c->m[m];
        c->all[m] = m;
        mo->next_t = mo->due_t = NEVER;
        mo->gen = mo->stopped_gen = -1;
        mo->last_edge = -(INT64_C(1) << 62);
        mo->ready = mo->ready_at = mo->last_fall = -(INT64_C(1) << 62);
        mo->out_dir = -1;
        mo->watch = 1;
        mo->rel_at = NEVER;
        mo->end[0] = mo->end[1] = -1;
    }
    return 0;
}

static PyObject *Core_motor(CoreObject *self, PyObject *args) {
    int m, lag_faults, end_lo, end_hi, invert;
    long long min_iv, slide, start_gap, width, debounce, micro, setup, hold;
    double lag_k, max_lag, start_speed;
    if (!PyArg_ParseTuple(args, "iLLLLLLdddpiipLL", &m, &min_iv, &slide, &start_gap, &width,
                          &debounce, &micro, &lag_k, &max_lag, &start_speed, &lag_faults,
                          &end_lo, &end_hi, &invert, &setup, &hold))
        return NULL;
    if (core_usable(self, 0) < 0)
        return NULL;
    struct core *c = &self->c;
    if (m < 0 || m >= c->n || end_lo < -1 || end_lo >= c->nlines || end_hi < -1 ||
        end_hi >= c->nlines || micro < 1 || min_iv < 0 || width < 0 || setup < 0 || hold < 0)
        return PyErr_Format(PyExc_ValueError, "motor %d: a value out of range", m);
    struct motor *mo = &c->m[m];
    mo->min_iv = min_iv;
    mo->slide_after = slide;
    mo->start_gap = start_gap;
    mo->width = width;
    mo->debounce = debounce;
    mo->microsteps = micro;
    mo->lag_k = lag_k;
    mo->max_lag = max_lag;
    mo->start_speed = start_speed;
    mo->lag_faults = lag_faults;
    mo->end[0] = end_lo;
    mo->end[1] = end_hi;
    mo->invert_dir = invert;
    mo->dir_setup = setup;
    mo->dir_hold = hold;
    self->configured[m] |= 1;
    Py_RETURN_NONE;
}

static PyObject *Core_start(CoreObject *self, PyObject *args) {
    int virt;
    long long now;
    if (!PyArg_ParseTuple(args, "pL", &virt, &now) || core_usable(self, 0) < 0)
        return NULL;
    struct core *c = &self->c;
    if (c->kind == LINES_NONE)
        return PyErr_Format(PyExc_RuntimeError, "no lines given (gpio() or sim())");
    for (int m = 0; m < c->n; m++)
        if (self->configured[m] != 3)
            return PyErr_Format(PyExc_RuntimeError, "motor %d is not configured", m);
    c->virt = virt;
    c->vnow = now;
    c->started = 1;
    Py_RETURN_NONE;
}

static PyObject *virtual_only(CoreObject *self) {
    if (core_usable(self, 1) < 0)
        return NULL;
    if (!self->c.virt)
        return PyErr_Format(PyExc_RuntimeError, "the step core runs on the real clock");
    return Py_None;
}

static PyObject *Core_refill(CoreObject *self, PyObject *unused) {
    (void)unused;
    if (virtual_only(self) == NULL)
        return NULL;
    core_refill(&self->c);
    Py_RETURN_NONE;
}

static PyObject *Core_deadline(CoreObject *self, PyObject *unused) {
    (void)unused;
    if (core_usable(self, 1) < 0)
        return NULL;
    int64_t d = core_deadline(&self->c);
    if (d == NEVER)
        Py_RETURN_NONE;
    return PyLong_FromLongLong(d);
}

static PyObject *Core_advance(CoreObject *self, PyObject *args) {
    long long now;
    if (!PyArg_ParseTuple(args, "L", &now) || virtual_only(self) == NULL)
        return NULL;
    core_advance(&self->c, now);
    Py_RETURN_NONE;
}

static PyObject *Core_run_until(CoreObject *self, PyObject *args) {
    long long until;
    if (!PyArg_ParseTuple(args, "L", &until) || virtual_only(self) == NULL)
        return NULL;
    core_run_until(&self->c, until);
    Py_RETURN_NONE;
}

static PyObject *Core_clock(CoreObject *self, PyObject *args) {
    long long now;
    if (!PyArg_ParseTuple(args, "L", &now) || virtual_only(self) == NULL)
        return NULL;
    if (now > self->c.vnow)
        self->c.vnow = now; /* a virtual clock never goes back */
    Py_RETURN_NONE;
}

static PyObject *Core_now(CoreObject *self, PyObject *unused) {
    (void)unused;
    if (core_usable(self, 1) < 0)
        return NULL;
    return PyLong_FromLongLong(core_now(&self->c));
}

static PyObject *Core_run(CoreObject *self, PyObject *args) {
    int wake_fd, event_fd, parent;
    if (!PyArg_ParseTuple(args, "iii", &wake_fd, &event_fd, &parent) || core_usable(self, 1) < 0)
        return NULL;
    struct core *c = &self->c;
    if (c->virt)
        return PyErr_Format(PyExc_RuntimeError, "a virtual clock is driven by its caller");
    c->wake_fd = wake_fd;
    c->event_fd = event_fd;
    c->parent = parent;
    Py_BEGIN_ALLOW_THREADS core_run(c);
    Py_END_ALLOW_THREADS c->event_fd = -1;
    Py_RETURN_NONE;
}

static PyObject *Core_halt_all(CoreObject *self, PyObject *unused) {
    (void)unused;
    if (core_usable(self, 1) < 0)
        return NULL;
    core_halt_all(&self->c);
    Py_RETURN_NONE;
}

static PyObject *Core_timeline(CoreObject *self, PyObject *unused) {
    (void)unused;
    if (core_usable(self, -1) < 0)
        return NULL;
    struct sim *s = &self->c.sim;
    PyObject *out = PyList_New((Py_ssize_t)s->tl_len);
    if (out == NULL)
        return NULL;
    for (int64_t i = 0; i < s->tl_len; i++) {
        const struct tl_entry *e = &s->tl[(s->tl_start + i) % s->tl_cap];
        PyObject *t = Py_BuildValue("(LiiiL)", (long long)e->t, e->kind, e->axis, e->value,
                                    (long long)e->call);
        if (t == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyList_SET_ITEM(out, (Py_ssize_t)i, t);
    }
    s->tl_len = s->tl_start = 0;
    return out;
}

static PyObject *Core_close(CoreObject *self, PyObject *unused) {
    (void)unused;
    release(self);
    Py_RETURN_NONE;
}

static PyMethodDef Core_methods[] = {
    {"motor", (PyCFunction)Core_motor, METH_VARARGS,
     "motor(m, min_iv, slide_after, start_gap, width, debounce, microsteps, lag_k, max_lag, "
     "start_speed, lag_faults, end_lo, end_hi, invert_dir, dir_setup, dir_hold): motor m's "
     "limits (ticks) and end-stop lines (-1: none)"},
    {"level", (PyCFunction)Core_level, METH_VARARGS, "level(line, active): an initial level"},
    {"gpio", (PyCFunction)Core_gpio, METH_VARARGS,
     "gpio(outputs, step, dir, inputs, active_low): GPIO chardev line requests"},
    {"sim", (PyCFunction)Core_sim, METH_VARARGS,
     "sim(cells, endstop_min, endstop_max, switches, axis_of, timeline_len): the mock's "
     "mechanics"},
    {"sim_error", (PyCFunction)Core_sim_error, METH_VARARGS,
     "sim_error(kind, axis, text or None): writes to that simulated line fail with text"},
    {"start", (PyCFunction)Core_start, METH_VARARGS, "start(virtual, now_ns)"},
    {"refill", (PyCFunction)Core_refill, METH_NOARGS, "virtual clock: new work, end stops"},
    {"deadline", (PyCFunction)Core_deadline, METH_NOARGS, "the next step's due tick, or None"},
    {"advance", (PyCFunction)Core_advance, METH_VARARGS, "virtual clock: everything due at now"},
    {"run_until", (PyCFunction)Core_run_until, METH_VARARGS,
     "virtual clock: every edge up to tick t, the clock moved to each"},
    {"clock", (PyCFunction)Core_clock, METH_VARARGS,
     "virtual clock: the caller's clock moved on to now (ticks)"},
    {"now", (PyCFunction)Core_now, METH_NOARGS, "the core's time (ticks)"},
    {"run", (PyCFunction)Core_run, METH_VARARGS,
     "run(wake_fd, event_fd, parent): the real clock's loop (the GIL released) until the "
     "run cell is 0 or the parent is gone"},
    {"halt_all", (PyCFunction)Core_halt_all, METH_NOARGS, "every motor stopped"},
    {"timeline", (PyCFunction)Core_timeline, METH_NOARGS,
     "the simulated lines' edges since the last call: (t, kind, axis, value, call)"},
    {"close", (PyCFunction)Core_close, METH_NOARGS, "release the block and the memory"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "motorctl.motion.executors._stepcore.Core",
    .tp_doc = "The compiled step core over a shared block (its compiled_core module).",
    .tp_basicsize = sizeof(CoreObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Core_init,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_methods = Core_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_stepcore",
    "The compiled step core (motion/executors/csrc); driven by its compiled_core module.", -1,
    NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__stepcore(void) {
    if (PyType_Ready(&CoreType) < 0)
        return NULL;
    PyObject *mod = PyModule_Create(&module);
    if (mod == NULL)
        return NULL;
    Py_INCREF(&CoreType);
    if (PyModule_AddObject(mod, "Core", (PyObject *)&CoreType) < 0 ||
        PyModule_AddIntConstant(mod, "COUNTERS", N_COUNTERS) < 0 ||
        PyModule_AddIntConstant(mod, "MOTOR_CELLS", N_MOTOR_CELLS) < 0 ||
        PyModule_AddIntConstant(mod, "LATENCY_CELLS", L_CELLS) < 0 ||
        PyModule_AddIntConstant(mod, "SEGMENT_RECORD", SEG_FIELDS * 8) < 0 ||
        PyModule_AddIntConstant(mod, "STOP_RECORD", STOP_FIELDS * 8) < 0 ||
        PyModule_AddIntConstant(mod, "EVENT_RECORD", EVENT_BYTES) < 0) {
        Py_DECREF(&CoreType);
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
