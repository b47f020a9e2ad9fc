/* The compiled step core's Python type (module.c), as module_lines.c shares it: the object
 * and the checks every method makes first. Apart from stepcore.h on purpose: the core's own
 * files (core.c, drive.c, rings.c, lines_gpio.c, lines_sim.c) know nothing of Python. */
#ifndef MOTORCTL_STEPCORE_MODULE_H
#define MOTORCTL_STEPCORE_MODULE_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "stepcore.h"

typedef struct {
    PyObject_HEAD struct core c;
    Py_buffer block, cells;
    int have_block, have_cells, closed;
    int *configured;
} CoreObject;

/* sets the exception; -1 */
int core_fail(PyObject *type, const char *msg);
/* 0 when the core is open and, for started >= 0, started (1) or not yet (0); else -1 */
int core_usable(CoreObject *self, int started);

/* module_lines.c: the methods that hand the core its lines */
PyObject *Core_level(CoreObject *self, PyObject *args);
PyObject *Core_gpio(CoreObject *self, PyObject *args);
PyObject *Core_sim(CoreObject *self, PyObject *args);
PyObject *Core_sim_error(CoreObject *self, PyObject *args);

#endif
