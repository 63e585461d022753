"""Property test: a damaged lab config is refused with a one-line ConfigError, never another exception.

Hypothesis mutates the example config the way configs get damaged: keys deleted, values
replaced by any YAML type (including NaN, mixed-type keys and nested lists), unknown keys added,
the text cut short or sprinkled with random characters. :func:`load_lab_config` must either
load it or raise :class:`ConfigError` with a non-empty, one-line message.
"""

import copy

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from marlander_lite.deploy.config import EXAMPLE_CONFIG, ConfigError, load_lab_config

FUZZ = settings(
    max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
EXAMPLE = yaml.safe_load(EXAMPLE_CONFIG.read_text())


def paths(node, prefix=()):
    """Every key path of a parsed YAML tree, e.g. ``('drones', 1, 'uri')``."""
    found = [prefix] if prefix else []
    children = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, child in children:
        found += paths(child, (*prefix, key))
    return found


PATHS = paths(EXAMPLE)
keys = st.none() | st.booleans() | st.integers(-5, 5) | st.floats() | st.text(max_size=6)
yaml_values = st.recursive(
    keys,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(keys, inner, max_size=3),
    max_leaves=6,
)


def loads_or_refuses(path) -> None:
    try:
        load_lab_config(path)
    except ConfigError as error:
        message = str(error)
        assert message.strip() and "\n" not in message, message


@FUZZ
@given(data=st.data())
def test_key_and_value_mutations_are_refused_cleanly(tmp_path, data):
    config = copy.deepcopy(EXAMPLE)
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(PATHS))
        parent = config
        try:
            for key in path[:-1]:
                parent = parent[key]
            action = data.draw(st.sampled_from(["delete", "replace", "add"]))
            if action == "delete":
                del parent[path[-1]]
            elif action == "replace":
                parent[path[-1]] = data.draw(yaml_values)
            elif isinstance(parent, dict):
                parent[data.draw(keys)] = data.draw(yaml_values)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier mutation removed or replaced this path
    file = tmp_path / "lab.yaml"
    file.write_text(yaml.safe_dump(config, allow_unicode=True))
    loads_or_refuses(file)


@FUZZ
@given(data=st.data())
def test_text_damage_is_refused_cleanly(tmp_path, data):
    text = EXAMPLE_CONFIG.read_text()
    if data.draw(st.booleans()):
        text = text[: data.draw(st.integers(0, len(text)))]
    for _ in range(data.draw(st.integers(0, 5))):
        at = data.draw(st.integers(0, len(text)))
        text = text[:at] + data.draw(st.text(alphabet=st.characters(codec="utf-8"), max_size=4)) + text[at:]
    file = tmp_path / "lab.yaml"
    file.write_text(text, encoding="utf-8", errors="surrogatepass")
    loads_or_refuses(file)
