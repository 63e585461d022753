"""Property test: a damaged policy file is refused with a PolicyFileError, never another exception.

Hypothesis mutates a valid small policy file in the ways a file gets damaged or forged: cut
short, random bytes over the safetensors header, contract fields deleted, replaced by values
of any JSON type, or added, random contract text, tensors dropped, reshaped or filled with
NaN. :func:`load_policy` must either load it (some mutations leave a valid file) or raise
:class:`PolicyFileError` with a message.
"""

import json
import struct
from dataclasses import asdict

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from safetensors.numpy import save_file

from marlander_lite.policy_file import FORMAT, FORMAT_VERSION, PolicyContract, PolicyFileError, load_policy

FUZZ = settings(
    max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

CONTRACT = asdict(
    PolicyContract(
        num_drones=2, max_speed=3.0, policy_hz=24.0, activation="tanh", hidden_sizes=(4,), normalize_observations=True
    )
)
TENSORS = {
    "actor.0.weight": np.full((4, 26), 0.1),
    "actor.0.bias": np.zeros(4),
    "actor.1.weight": np.full((6, 4), 0.1),
    "actor.1.bias": np.zeros(6),
    "obs_mean": np.zeros(26),
    "obs_var": np.ones(26),
}
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=6,
)


def write(path, contract, tensors, meta=None) -> bytes:
    metadata = {"format": FORMAT, "format_version": str(FORMAT_VERSION), **(meta or {})}
    metadata["contract"] = contract if isinstance(contract, str) else json.dumps(contract)
    save_file({k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}, str(path), metadata=metadata)
    return path.read_bytes()


def loads_or_refuses(path) -> None:
    try:
        load_policy(path)
    except PolicyFileError as error:
        assert str(error).strip()


@FUZZ
@given(data=st.data())
def test_contract_mutations_are_refused_cleanly(tmp_path, data):
    contract = dict(CONTRACT)
    for _ in range(data.draw(st.integers(1, 3))):
        key = data.draw(st.sampled_from([*CONTRACT, "unknown_field"]))
        if data.draw(st.booleans()):
            contract.pop(key, None)
        else:
            contract[key] = data.draw(json_values)
    text = data.draw(st.sampled_from(["json", "raw"]))
    body = json.dumps(contract) if text == "json" else data.draw(st.text(max_size=40))
    write(tmp_path / "p.safetensors", body, TENSORS)
    loads_or_refuses(tmp_path / "p.safetensors")


@FUZZ
@given(data=st.data())
def test_tensor_mutations_are_refused_cleanly(tmp_path, data):
    tensors = dict(TENSORS)
    name = data.draw(st.sampled_from([*TENSORS, "actor.2.weight"]))
    action = data.draw(st.sampled_from(["drop", "reshape", "fill"]))
    if action == "drop":
        tensors.pop(name, None)
    elif action == "reshape":
        shape = data.draw(st.lists(st.integers(0, 30), min_size=0, max_size=3))
        tensors[name] = np.zeros(shape)
    else:
        fill = data.draw(st.floats(width=32) | st.just(3e38))
        tensors[name] = np.full(TENSORS.get(name, np.zeros((6, 6))).shape, fill)
    write(tmp_path / "p.safetensors", CONTRACT, tensors)
    loads_or_refuses(tmp_path / "p.safetensors")


@FUZZ
@given(data=st.data())
def test_byte_damage_is_refused_cleanly(tmp_path, data):
    path = tmp_path / "p.safetensors"
    raw = bytearray(write(path, CONTRACT, TENSORS))
    header_end = 8 + struct.unpack("<Q", raw[:8])[0]
    if data.draw(st.booleans()):  # random bytes over the length field and the JSON header
        for _ in range(data.draw(st.integers(1, 8))):
            raw[data.draw(st.integers(0, header_end - 1))] = data.draw(st.integers(0, 255))
    else:  # cut short anywhere
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    path.write_bytes(bytes(raw))
    loads_or_refuses(path)
