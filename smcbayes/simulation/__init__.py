"""The simulator seam: one protocol for every forward run of every stage.

- :mod:`~smcbayes.simulation.objective`: tasks (a block of parameter vectors on one
  configuration), the simulator protocol, and the loss of simulated curves against data;
- :mod:`~smcbayes.simulation.executors`: where tasks run (in process, a local process
  pool, a Dask cluster), behind one small contract;
- :mod:`~smcbayes.simulation.executors.external`: the user's own solver by command line;
- :mod:`~smcbayes.simulation.problem`: a calibration problem built from a project.
"""
