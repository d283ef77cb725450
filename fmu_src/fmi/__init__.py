"""The generic FMI 2.0 layer of every flightgp FMU: the base slave (:mod:`fmu_src.fmi.slave`) and
its C twin (``fmi2_slave.c``, ``model.h``), GP prediction in C for the native models
(``gp_predict.c``, ``gp_predict.h``), the runtime every pythonfmu FMU carries
(:mod:`fmu_src.fmi.runtime`), what every grey-box (RKGP) FMU runs (:mod:`fmu_src.fmi.greybox`;
in C ``greybox.c``, ``greybox.h``) and its builders share (:mod:`fmu_src.fmi.greybox_build`),
pythonfmu packaging (:mod:`fmu_src.fmi.pythonfmu`), native compilation
(:mod:`fmu_src.fmi.native`), FMU names and the variables of recorded signals."""
