"""The exported FMU's speed: the paper's pump (config/circuits/paper.yaml) as an FMI 2.0
co-simulation FMU stepped by FMPy at a 1 ms communication step, a current step and a held
load, against the same circuit stepped by ``Simulator.step()`` in this process (the
baseline, what the simulator node does per step). Medians of 5 runs of 2 simulated s.
"""

from pathlib import Path
import shutil
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from hydropump_ctrl.fmi.export import export_fmu  # noqa: E402
from hydropump_sim.circuit import default_circuit_path, load_circuit  # noqa: E402
from hydropump_sim.simulate import Simulator  # noqa: E402

from common import emit, median_time, row  # noqa: E402

DURATION, DT = 2.0, 1.0e-3
N = int(round(DURATION / DT))


def current(k: int) -> float:
    return 0.58 if k * DT >= 0.5 else 0.5


def main():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'paper.fmu'
        export_fmu(path)
        md = read_model_description(str(path))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        outs = [vr[v.name] for v in md.modelVariables if v.causality == 'output']
        where = extract(str(path))

        def fmu_run():
            fmu = FMU2Slave(guid=md.guid, unzipDirectory=where,
                            modelIdentifier=md.coSimulation.modelIdentifier,
                            instanceName='bench')
            fmu.instantiate()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            for k in range(N):
                fmu.setReal([vr['pump.current']], [current(k)])
                fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
                fmu.getReal(outs)
            fmu.terminate()
            fmu.freeInstance()

        circuit = load_circuit(default_circuit_path())

        def direct_run():
            sim = Simulator(circuit, DT)
            for k in range(N):
                sim.set_input('pump.current', current(k))
                sim.step()
                sim.outputs()
        fmu_run()
        direct_run()      # compiled and cached before the timings
        t_fmu, _ = median_time(fmu_run)
        t_direct, _ = median_time(direct_run)
        shutil.rmtree(where, ignore_errors=True)
    emit([
        row('paper pump FMU in FMPy, 1 ms steps: real-time factor', DURATION / t_fmu, 'x',
            note=f'{t_fmu:.3g} s for {DURATION:g} s, initialisation included'),
        row('paper pump FMU: speed against Simulator.step() in-process', t_direct / t_fmu,
            'x', note=f'Simulator.step() {DURATION / t_direct:.3g}x real time, same run'),
    ])


if __name__ == '__main__':
    main()
