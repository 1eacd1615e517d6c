"""Figures say what they show in words: swept columns get names with units, the speed/accuracy chart states the
default model's error against the reference."""

from __future__ import annotations

import matplotlib.image as mpimg
import pandas as pd

from beambench.common.resources import shipped_dir
from beambench.studies.ladder.figures import default_model_sentence, plot_speed_accuracy, plot_stability_map
from beambench.studies.ladder.run import summarize
from beambench.studies.sweep.figure import axis_label, plot_sweep
from beambench.studies.sweep.run import SweepSpec


def test_swept_columns_are_named_in_words_with_units():
    assert axis_label("twist_deg") == "twist angle φ (deg)"
    assert axis_label("gap_mm") == "plate gap h′ (mm)"
    assert axis_label("some_new_column") == "some new column"  # never the raw snake_case name


def test_the_twist_sweep_axis_is_labelled_in_words(tmp_path):
    spec = SweepSpec.model_validate(
        {"name": "twist", "scene": "free_beam", "frequencies": [15], "grid": {"twist_deg": [0, 90, 180]}}
    )
    df = pd.DataFrame(
        {
            "twist_deg": [0.0, 90.0, 180.0],
            "tip_major_mm": [1.0, 2.0, 3.0],
            "tip_minor_mm": [0.1, 0.2, 0.3],
            "tip_tilt_deg": [0.0, 5.0, 10.0],
        }
    )
    labels: list[str] = []
    from matplotlib.figure import Figure

    original = Figure.savefig

    def spy(self, *args, **kwargs):
        labels.extend(ax.get_xlabel() for ax in self.axes)
        return original(self, *args, **kwargs)

    Figure.savefig = spy  # type: ignore[method-assign]
    try:
        path = plot_sweep(df, spec, tmp_path / "twist.png")
    finally:
        Figure.savefig = original  # type: ignore[method-assign]
    assert path is not None and path.is_file()
    assert labels and all(lbl == "twist angle φ (deg)" for lbl in labels)


def test_the_speed_accuracy_chart_states_the_default_models_error(tmp_path):
    table = pd.read_csv(shipped_dir("sim_backend") / "ladder_table.csv")
    summary = summarize(table)
    sentence = default_model_sentence(summary)
    assert sentence is not None and "default model (PRB3" in sentence and " mm on average" in sentence
    row = summary[(summary.model == "prb3") & (summary.integrator == "implicitfast") & (summary.timestep == 1e-4)]
    assert f"{row.err_mean_mm.iloc[0]:.2g} mm" in sentence  # the figure's own number, not a fixed text
    png = plot_speed_accuracy(summary, tmp_path / "sa.png")
    assert mpimg.imread(png).shape[0] > 500
    # two models' columns of the shipped table (all seven: 35 panels, 5 s; the map of a whole ladder
    # run is drawn by test_physics_ladder's write_outputs)
    stab = plot_stability_map(table, tmp_path / "stab.png", models=("prb3", "rod5"))
    assert stab.is_file()
