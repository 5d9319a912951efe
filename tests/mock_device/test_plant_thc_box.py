"""The external THC box: up/down around the set point with a dead band, only with arc OK."""

from mock_device.plant import InputBit, Plant, ThcBox

from .plant_helpers import DT_S, fire, goto_xy, quiet, set_height


def test_box_signals_up_below_and_down_above_the_dead_band() -> None:
    """v < set - band → up; v > set + band → down; inside → neither; no arc OK → neither."""
    box = ThcBox(set_voltage_v=125.0, deadband_v=1.0, filter_ms=0.0)
    cases = {
        120.0: (True, False),
        124.5: (False, False),
        125.9: (False, False),
        130.0: (False, True),
    }
    for volts, expected in cases.items():
        box.update(volts, True, DT_S)
        assert (box.up, box.down) == expected, volts
    box.update(100.0, False, DT_S)
    assert (box.up, box.down) == (False, False)


def test_plant_exposes_the_box_outputs_on_the_input_bits() -> None:
    """Torch too high during a cut → THC_DOWN; too low → THC_UP; torch off → neither."""
    plant = Plant(quiet(), seed=1)
    goto_xy(plant, 100.0, 100.0)
    plant.gantry.feed_line("G1 X600 Y100 F5500")  # moving: no slow-down rise
    fire(plant, 3.0)
    plant.advance(1.0)
    assert plant.inputs() & InputBit.THC_DOWN
    assert not plant.inputs() & InputBit.THC_UP
    set_height(plant, 0.5)
    plant.advance(0.05)
    assert plant.inputs() & InputBit.THC_UP
    plant.set_torch(False)
    plant.advance(0.01)
    assert not plant.inputs() & (InputBit.THC_UP | InputBit.THC_DOWN)
