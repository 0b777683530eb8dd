"""Draw docs/img/calibration.png: a calibration's before and after on one bag.

Four bags of the fine model with the usual free set perturbed (mu_a x1.25, P_a_bar x0.85,
V_l x1.35, mu_u x0.9) through the bench sensors, calibrated from config/pump.yaml; the figure
shows the load-pressure-step bag, measured against the model at the start and calibrated.
Run: ``.venv/bin/python docs/draw_calibration.py`` (about 20 s).
"""

from pathlib import Path
import tempfile

from hydropump_ctrl.ident import read_recordings, recording_to_bag
from hydropump_ctrl.ident.calibrate import calibrate, params_with
from hydropump_ctrl.ident.calibrate.writers import plot_comparison
from hydropump_ctrl.ident.design import candidate_inputs
from hydropump_ctrl.ident.synthetic import plant_recording
from hydropump_sim.params import load_params
from hydropump_sim.sensors import load_profile, SensorProfile

ROOT = Path(__file__).resolve().parents[1]
FREE = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')


def main() -> None:
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f
                                     for n, f in zip(FREE, (1.25, 0.85, 1.35, 0.9))])
    sensors = load_profile(ROOT / 'config' / 'bench.yaml').sensors
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for k, (name, inp) in enumerate(candidate_inputs(truth, dwell=0.8).items()):
            rec = plant_recording(truth, inp['current'], load_pressure=inp['load_pressure'],
                                  profile=SensorProfile(sensors, seed=k + 1), name=name)
            paths.append(recording_to_bag(rec, Path(tmp) / f'bag{k}'))
        cal = calibrate(read_recordings(paths), base, FREE, signals=[
            'line_flow', 'line_pressure', 'actuator_pressure', 'actuator_position'])
    k = len(cal.experiments) - 1
    plot_comparison(cal.experiments[k], cal.predictions[k], ROOT / 'docs' / 'img' /
                    'calibration.png', cal.predictions_before[k],
                    title='load-pressure steps: measured, model at the start (dashed) and '
                          'calibrated')
    for p in cal.estimates:
        print(f'{p.name}: {p.initial:.5g} -> {p.value:.5g} (truth {truth.flat()[p.name]:.5g})')


if __name__ == '__main__':
    main()
