"""The ``process`` step executor: the step core in a process of its own."""
