"""Write the slow thermal example of docs/process-plants.md: a heater in an insulated box under a 0/1 relay.

The box: G(s) = 32 e^{-17 s} / ((1500 s + 1)(100 s + 1)) [degC per unit duty], at 20 degC ambient
with the heater off. A thermostat (2 degC band: +-1 degC about 40 degC) switches the heater on its
own clock (every 0.5 s, on a reading with 0.05 degC noise); a recorder logs the heater state and the
temperature every 1-7 s (jittered), for 4 hours: cycles of about 14 minutes. Simulated by
tests/thermal_sim.py (exact, independent of mrftcli), written as a CSV (time [s], u_relay, y_output).

Run: ``python scripts/make_thermal_example.py [OUT.csv]`` (default heater.csv), then
``mrft-ident analyze heater.csv --command-topic u_relay --output-topic y_output --model sopdt``.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from process_sim import write_csv  # noqa: E402
from thermal_sim import RelayWindow, simulate_relay  # noqa: E402

BOX = {"K": 32.0, "T1": 1500.0, "T2": 100.0, "tau": 17.0}
AMBIENT, SETPOINT, BAND_HALF = 20.0, 40.0, 1.0


def main() -> None:
    out = sys.argv[1] if len(sys.argv) > 1 else "heater.csv"
    t, u, y = simulate_relay("sopdt", BOX, [RelayWindow(1.0, 0.0, BAND_HALF, 4 * 3600.0)], setpoint=SETPOINT,
                             baseline=AMBIENT, sample_s=(1.0, 7.0), noise_std=0.05, seed=2026, decide_s=0.5)
    write_csv(out, t, u, y)
    print(f"wrote {out}: {t.size} samples over {t[-1] / 3600:.1f} h (intervals 1-7 s); truth {BOX}, ambient "
          f"{AMBIENT} degC")


if __name__ == "__main__":
    main()
