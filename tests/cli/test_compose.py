"""Plain overrides, parsed by Hydra's override parser, are composed without Hydra's compose, into
the config Hydra's compose API gives; every other override is still composed by Hydra (issue 31:
calibrate's start-up; issue 39: no copy of Hydra's grammar)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from magbench.cli.config import UsageError, _compose_plain, compose_config, config_dir

#: Overrides composed without Hydra: every kind of value Hydra's grammar types (null, bools,
#: ints with underscores or signs, floats of every form, text that only looks like a number)
#: and flat lists of them, on the keys calibrate, apply and the sweeps read.
PLAIN = [
    ["file=rec.csv"], ["out="], ["results_dir="], ["file=/tmp/a-b/c.d.csv"], ["file=a:b"],
    ["file=-"], ["file=a@b%c*d?e|f"], ["file=1e"], ["file=0x10"], ["file=1_"], ["file=007"],
    ["file=infinity"], ["file=00.5"], ["file=1..2"], ["date=2021-01-01"],
    ["seed=1_000"], ["seed=+5"], ["seed=-0"], ["n_jobs=-1"], ["delta=1e9"], ["delta=1E-3"],
    ["delta=.5"], ["delta=5."], ["delta=inf"], ["delta=-inf"], ["delta=1_0.5"],
    ["delta=1.5e3"], ["progress=True"], ["progress=FALSE"], ["method=NULL"],
    ["method=null_x"], ["call_timeout_s=null"], ["units=0.0625uT"], ["field_strength=48uT"],
    ["instance=1"], ["instance=1.0"], ["columns=[mx,my,mz]"], ["columns=[0,1,2]"],
    ["columns=[]"], ["columns=[1e3,true,null,x]"], ["columns=[a:b]"], ["columns=[/x/y]"],
    ["columns=[+1,-2]"], ["columns=[.5]"], ["columns=[1_0]"], ["location=[52.51,13.33]"],
    ["plugins=[a.b,c]"], ["nominal.alpha=[1,2]"], ["gate.warn_error_pct=20"],
    ["++options.magical.max_iter=2"], ["++options.magical.tol=1e-9"],
    ["++options.a.b.c=[x]"], ["++seed=5"], ["seed=1", "seed=2"],
    ["file=a.csv", "out=b", "columns=[mx,my,bz]", "bootstrap=0", "overwrite=true"],
    ["file='a b.csv'"], ["file=a b.csv"], ["file=a\\ b.csv"], ["columns=[a,'b c']"],
    ["file=\"x,y\""],
]

#: Overrides left to Hydra: another sweep, nested or interpolated values, a sweep of values,
#: a key that is not there without '++', a section replaced by a value, '+', '~' or a package.
HYDRA = [["sweep=gamma"], ["++sweep.rate_hz=5"], ["columns=[[0],1,2]"],
         ["file=${oc.env:HOME}"], ["file='${oc.env:HOME}'"], ["options={}"], ["columns=[a,,b]"],
         ["location=52.5,13.3"], ["gate=5"], ["nominal.K.x=1"], ["options.magical.tol=1"],
         ["+seed=1"], ["~seed"], ["seed@x=1"], ["file=a=b=c,d"]]


def hydra_compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def same(a: object, b: object) -> bool:
    """Equal as data, with the same types (1 is not 1.0 or '1'), NaN equal to NaN."""
    if isinstance(a, dict) and isinstance(b, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("overrides", PLAIN, ids=" ".join)
def test_plain_overrides_give_the_config_hydra_composes(overrides):
    plain = _compose_plain(overrides)
    assert plain is not None, "composed by Hydra, not by the plain path"
    hydra = hydra_compose(overrides)
    assert same(OmegaConf.to_container(plain), OmegaConf.to_container(hydra))
    assert same(OmegaConf.to_container(plain, resolve=True),
                OmegaConf.to_container(hydra, resolve=True))
    assert OmegaConf.is_struct(plain) and OmegaConf.is_struct(hydra)


@pytest.mark.parametrize("overrides", HYDRA, ids=" ".join)
def test_other_overrides_are_left_to_hydra(overrides):
    assert _compose_plain(overrides) is None


def test_nan_is_typed_as_hydra_types_it():
    for text in ("nan", "NaN", "-nan"):
        assert math.isnan(_compose_plain([f"delta={text}"]).delta)
        assert math.isnan(hydra_compose([f"delta={text}"]).delta)


def test_hydra_still_composes_and_words_what_the_plain_path_leaves():
    assert compose_config(["sweep=gamma"]).sweep.name == "gamma"
    assert compose_config(["file='a b.csv'"]).file == "a b.csv"
    with pytest.raises(UsageError, match="location"):
        compose_config(["location=52.5,13.3"])       # Hydra's sweep of values, refused
    with pytest.raises(UsageError, match="unknown key 'nosuchkey'"):
        compose_config(["nosuchkey=1"])


def test_a_config_access_missing_a_key_behaves_as_hydras():
    plain, hydra = _compose_plain(["file=x.csv"]), hydra_compose(["file=x.csv"])
    assert plain.get("no_such_key", 5) == hydra.get("no_such_key", 5) == 5
    for cfg in (plain, hydra):
        with pytest.raises(Exception, match="no_such_key"):
            cfg.no_such_key  # noqa: B018


#: Run in a fresh interpreter: calibrate on a CSV file, then which modules were imported.
_IMPORTED = """
import json, sys
from magbench.cli import main
code = main(sys.argv[1:])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def test_calibrate_on_a_csv_file_does_not_compose_with_hydra(tmp_path):
    import numpy as np
    import pandas as pd

    from magbench.core.geometry import fibonacci_sphere

    y = 40.0 * (fibonacci_sphere(400) * [1.1, 0.9, 1.0] + [0.2, -0.1, 0.05])
    pd.DataFrame(y + np.random.default_rng(0).normal(0, 0.05, y.shape),
                 columns=["mx", "my", "mz"]).to_csv(tmp_path / "rec.csv", index=False)
    done = subprocess.run([sys.executable, "-c", _IMPORTED, "calibrate",
                           f"file={tmp_path / 'rec.csv'}", f"out={tmp_path / 'o'}",
                           "bootstrap=0"], capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["code"] == 0
    # Hydra's override parser only: compose would have loaded Hydra's core plugins (its
    # config sources and launcher).
    assert "hydra.core.override_parser.overrides_parser" in result["modules"]
    assert not any(m.startswith("hydra._internal.core_plugins") for m in result["modules"])
    assert (tmp_path / "o" / "calibration.json").exists()
