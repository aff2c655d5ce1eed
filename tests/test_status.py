"""Status bits: one `IntFlag`, a message per bit, module-level aliases that trace as int32."""

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
from jaxchain import status


def test_every_bit_has_one_message_and_an_alias():
  bits = [bit for bit in status.Status if bit]
  assert list(status.MESSAGES) == bits
  for bit in bits:
    assert getattr(status, bit.name) is bit
    assert bit.message == status.MESSAGES[bit] and bit.message
  assert status.OK == 0 and status.OK.message == ""
  both = status.FAST_BODY | status.CRUSHED
  assert both.message == f"{status.FAST_BODY.message}; {status.CRUSHED.message}"


def test_bits_trace_as_int32():
  code = jax.jit(lambda bad: jnp.where(bad, status.FAST_BODY, 0) | jnp.zeros((), jnp.int32))(True)
  assert code.dtype == jnp.int32 and int(code) == 1 << 5


def test_check_reports_each_bit_and_unknown_bits():
  world = jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)
  code = np.int32(status.CELL_OVERFLOW | status.NON_FINITE | 1 << 20)
  assert jc.check(world.replace(status=code)) == [
      f"world 0: {status.MESSAGES[status.CELL_OVERFLOW]}",
      f"world 0: {status.MESSAGES[status.NON_FINITE]}",
      "world 0: unknown status bits 0x100000"]
