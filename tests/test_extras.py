"""The optional extras install what their packages import.

CI runs `pip install -e ".[dev]"` on a fresh clone and then the suite: these tests
fail (they never skip) when an extra leaves out a module its packages need. gymnax
1.0.1 imports `six` in `import gymnax` without declaring it, so the `rl` extra lists
it. The bridges' ImportError names the module that is really missing.
"""

import subprocess
import sys



EXTRA_MODULES = ("gymnax", "gymnasium", "optax", "six", "stable_baselines3", "torch")


def test_extra_packages_import():
  """Each package of the rl and sb3 extras (all in dev) imports in a fresh interpreter."""
  code = ("import importlib\n"
          f"for m in {EXTRA_MODULES!r}:\n"
          "  try:\n"
          "    importlib.import_module(m)\n"
          "  except ImportError as e:\n"
          "    print(f'{m}: {type(e).__name__}: {e}')\n")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
  assert out.stdout == "", out.stdout


def test_bridge_classes_resolve():
  from gymnax.environments import environment
  from gymnasium.vector import VectorEnv
  from stable_baselines3.common.vec_env import VecEnv

  from jaxchain import bridges
  assert issubclass(bridges.GymnaxEnv, environment.Environment)
  assert issubclass(bridges.GymnasiumVectorEnv, VectorEnv)
  assert issubclass(bridges.SB3VecEnv, VecEnv)


def _bridge_error(blocked: str, attribute: str) -> str:
  """The ImportError message of `bridges.<attribute>` in a fresh interpreter where
  importing `blocked` fails as it does when it is not installed (`None` in sys.modules
  raises ModuleNotFoundError with `name` set, as a missing module does)."""
  code = ("import sys\n"
          "from jaxchain import bridges\n"
          f"sys.modules[{blocked!r}] = None\n"
          "try:\n"
          f"  bridges.{attribute}\n"
          "except ImportError as e:\n"
          "  print(e)\n"
          "else:\n"
          "  print('NO ERROR')\n")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
  return out.stdout.strip()


def test_error_names_a_missing_dependency_not_the_installed_package():
  """gymnax installed, `six` missing (a fresh install before the fix): the message names
  `six` and does not tell the user to install gymnax."""
  message = _bridge_error("six", "GymnaxEnv")
  assert "'six'" in message and "pip install six" in message, message
  assert "gymnax is installed" in message and "not installed: pip install" not in message


def test_error_names_the_missing_package():
  message = _bridge_error("gymnax", "GymnaxEnv")
  assert message == ('jaxchain.bridges needs gymnax, which is not installed: '
                     'pip install "jaxchain[rl]"')
  message = _bridge_error("stable_baselines3", "SB3VecEnv")
  assert message == ('jaxchain.bridges needs stable_baselines3, which is not installed: '
                     'pip install "jaxchain[sb3]"')


def test_error_of_a_dependency_with_another_distribution_name():
  """A missing `absl` is installed by `pip install absl-py`."""
  message = _bridge_error("absl", "GymnaxEnv")
  assert "'absl'" in message and "pip install absl-py" in message, message
