"""The generic FMI 2.0 layer of every flightgp FMU: the base slave (:mod:`fmu_src.fmi.slave`) and
its C twin (``fmi2_slave.c``, ``model.h``), GP prediction in C for the native models
(``gp_predict.c``, ``gp_predict.h``), the runtime every pythonfmu FMU carries
(:mod:`fmu_src.fmi.runtime`), pythonfmu packaging (:mod:`fmu_src.fmi.pythonfmu`), native
compilation (:mod:`fmu_src.fmi.native`), FMU names and the variables of recorded signals."""
