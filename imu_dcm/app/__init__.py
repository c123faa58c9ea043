"""What the project's commands share: the option parsing, the value checks, the ``--rerun``
mode, the exit-code wrapper and the summary's common figures.

One module a concept, each imported by its full name (``from imu_dcm.app.run import
run_main``); this package imports none of them, so a command's ``--help`` loads only what it
names:

* :mod:`imu_dcm.app.options`: the one-line argument parser and the parsing of option text
  (``"a,b,c"``, ``--bias``, ``--mounting``), standard library only;
* :mod:`imu_dcm.app.checks`: the checks of a gyro bias and of a start attitude ``q_w_b``,
  shared by replay, batch and live, their libraries and their command lines;
* :mod:`imu_dcm.app.rerun_mode`: the ``--rerun`` mode (``spawn``, ``serve``,
  ``save:PATH.rrd``, ``off``) and rerun's own ``RERUN`` switch, standard library only;
* :mod:`imu_dcm.app.run`: the exit codes and :func:`~imu_dcm.app.run.run_main`, the wrapper
  every command's ``main`` runs in;
* :mod:`imu_dcm.app.progress`: the terminal progress line;
* :mod:`imu_dcm.app.summary`: the figures a replay's and a live run's summaries share;
* :mod:`imu_dcm.app.pages`: numpy's arrays in ordinary pages, for a command's process;
* :mod:`imu_dcm.app.beside`: two pure passes of one run side by side, on two threads.

It sits with the core: it imports only :mod:`imu_dcm.errors` and the core maths, never log
I/O, replay, live or the view.
"""
