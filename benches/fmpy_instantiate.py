"""Set-up time of repeated instances of one extracted FMU in one process (fmpy), e.g. a sweep.

Usage: .venv/bin/python benches/fmpy_instantiate.py [FMU] [N]
(default: target/fmu/tmt/mirror_voicecoil.fmu, 3 instances; `cargo xtask package tmt` first).
The first instance pays the built-in cell's eigensolve; later ones with the same parameters
reuse it (the structure model's cache, see fmus/structure_model).
"""
import sys
import time

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

fmu = sys.argv[1] if len(sys.argv) > 1 else "target/fmu/tmt/mirror_voicecoil.fmu"
n = int(sys.argv[2]) if len(sys.argv) > 2 else 3
unzipped = extract(fmu)
md = read_model_description(fmu)
for k in range(n):
    t = time.perf_counter()
    s = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"i{k}")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    print(f"instance {k}: instantiate to end of initialisation {time.perf_counter() - t:.3f} s")
    s.terminate()
    s.freeInstance()
