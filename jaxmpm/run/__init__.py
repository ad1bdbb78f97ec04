"""Running a step: simulate and its drivers, planning, restart files, ensembles, devices and the
compilation cache."""
