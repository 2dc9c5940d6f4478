"""The README's census table: ``python benchmarks/census_table.py`` prints it (markdown).

The stages of ``tests/plants/census.py`` (structures written after the zoo: Krasnosel'skii-
Pokrovskii operators, Bouc-Wen with exponents 2 and 0.5, a quadratic output, Dahl loops, a
saturated P-I model), each through exactly what ``benchmarks/zoo_table.py`` runs on the zoo:
``commission()``, then 1, 3 and 5 Hz sinusoids over 10-90 % of the stage's steady stroke, the
feedforward alone and with feedback and learning, and the noise floor. A few minutes; nothing
here is tuned on these stages.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from tests.plants.census import census  # noqa: E402
from zoo_table import main as print_table  # noqa: E402

if __name__ == "__main__":
    print_table(census(seed=0))
