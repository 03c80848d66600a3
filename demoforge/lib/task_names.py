"""The names of the task library's six tasks, in the thesis's order. Here, apart from the library
(lib/task_library), so that the command line lists them in `--help` without loading the tasks' models
(numpy, scipy)."""

TASK_NAMES = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")
