"""The work meter (`benchmarks/work_meter.py`) holds each scene's step under a budget.

The meter counts, from the jaxpr of one step, the elements every equation produces and
the elements gathers read, per body (loop bodies times their trip counts): what a step
costs on XLA:CPU, without timing it. A change that makes a scene's step do more work
than its budget fails here, so no change can quietly double the work again (issue 23:
the room of 64 had gone from 11,800 to 22,600 elements per body-step). The budgets are
the counts at the commit that set them plus a tenth; lower them when the step gets
leaner, and raise one only with a reason in the commit message.
"""

import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
import work_meter  # noqa: E402  (benchmarks/ is not a package)

# Per body-step: (elements produced, elements gathered) on the common path (the cheaper
# branch of each `lax.cond` over the batch) and on the worst one. Counted for the
# batch-minor core (issue 27: room 10,611 / 456 and 15,948 / 1,116; demo 8,604 / 456 and
# 17,236 / 1,608; platformer1 8,523 / 232 and 14,264 / 768), plus a tenth. Worst branch
# raised for issue 29 item 4: friction's second slip round (a third solve, run only in a
# batch where the second holding test dropped a link) is counted there: room 18,031 /
# 1,228, demo 20,332 / 1,800, platformer1 16,712 / 876, plus about 3%.
# Raised for issue 36 item 1, the closing stage: its overlap test after the passes (room
# 11,243 / 504, demo 9,094 / 448, platformer1 9,555 / 252, plus a tenth), and on the worst
# path its passes (every closing pass runs: room 57,669 / 3,852, demo 60,795 / 5,400,
# platformer1 47,116 / 2,628, plus about 3%).
BUDGETS = {
    "room of 64": ((12_400, 555), (59_400, 3_970)),
    "demo": ((10_000, 500), (62_600, 5_560)),
    "platformer1": ((10_500, 280), (48_500, 2_710)),
}


@pytest.fixture(scope="module")
def counts():
  return work_meter.scene_counts()


@pytest.mark.parametrize("scene", sorted(BUDGETS))
def test_step_work_is_within_its_budget(counts, scene):
  (elements, gathered), (worst_elements, worst_gathered) = BUDGETS[scene]
  got = counts[scene]
  stages = "\n".join(f"  {s:18s} {e:9,.0f} {g:7,.0f}" for s, (e, g) in got["stages"].items())
  detail = f"{scene} ({got['config']}), per body-step by stage:\n{stages}"
  assert got["elements"] <= elements, f"{got['elements']:,.0f} elements > {elements:,}: {detail}"
  assert got["gathered"] <= gathered, f"{got['gathered']:,.0f} gathered > {gathered:,}: {detail}"
  worst_e, worst_g = got["worst"]
  assert worst_e <= worst_elements and worst_g <= worst_gathered, (scene, got["worst"])


def test_the_meter_counts_loops_by_their_trips():
  import jax.numpy as jnp
  from jax import lax

  def f(x):  # 5 hops of a gather and an add over 10 elements, then one more add.
    idx = jnp.arange(10) % 3
    y = lax.fori_loop(0, 5, lambda _, y: y[idx] + 1.0, x)
    return y * 2.0

  count = work_meter.meter(f, jnp.zeros(10))
  assert sum(count.gathered.values()) == 50
  assert count.primitives["gather"] == 50 and count.primitives["mul"] == 10
  assert count.primitives["add"] >= 50  # The loop's add (and its counter's) five times.


def test_every_stage_is_named(counts):
  # Equations the meter cannot place are "other": a new module or helper is missing
  # from work_meter.STAGES / HELPERS, and the stage tables would hide its work.
  for scene, got in counts.items():
    other = got["stages"].get("other", (0.0, 0.0))
    assert other[0] <= 0.01 * got["elements"], f"{scene}: {other[0]:,.0f} elements unplaced"
