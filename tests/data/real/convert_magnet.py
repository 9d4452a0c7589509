"""Make the vendored real-data slices of this folder from their published sources (run once, by hand).

Needs h5py (hystbench does not depend on it: the slices are plain CSV + JSON once converted):

    pip download --no-deps -d /tmp/magnet mag-net==0.1.0          # the MagNet wheel, 18.8 MB
    git clone https://github.com/otvam/large_signal_ferrite_apec24 /tmp/lsf
    pip install --target /tmp/h5site h5py
    PYTHONPATH=/tmp/h5site python tests/data/real/convert_magnet.py \
        /tmp/magnet/mag_net-0.1.0-py3-none-any.whl /tmp/lsf/dataset/N87_mu_large tests/data/real

``convert_magnet.py --others WHEEL OUT`` writes the same two tables of the wheel's six other materials
(3C94, 3F4, 77, 78, N27, N30) into OUT: they are not vendored; they check the loss diagnosis on
materials it was not developed on.

What it writes (numbers unchanged: every value is the source's float64 written as its shortest
round-trip text, so float(text) gives back the source's number bit for bit):

* ``magnet_{MAT}_sine.csv`` + ``.json`` for N87, 3C90, 3E6, N49: the rows of the wheel's
  ``magnet/data/{MAT}_database.h5`` (a pandas HDFStore) with sinusoidal excitation (``Duty_1 == -1``;
  the other rows are triangular/trapezoidal), columns Frequency, Flux_Density (peak), Power_Loss; the
  Duty_* and Outlier_Factor columns are dropped, no row is removed.  The sidecar copies the store's
  own metadata (core shape, effective volume, temperature, measurement date).
* ``magnet_{MAT}_shapes.csv`` + ``.json``: the other rows of the same store (``Duty_1 != -1``:
  triangular and trapezoidal B(t)), columns Frequency, Flux_Density, Duty_1..4, Power_Loss;
  Outlier_Factor dropped, no row removed.  The sidecar says what the duties mean as MagNet's own
  code uses them (``hystbench.formats.flux_shapes`` rebuilds B(t) from them).
* ``N87_mu_large.csv`` + ``.json``: the large-signal complex relative permeability of N87 of
  ``dataset/N87_mu_large/`` (MATLAB text ``a+bi``, ``NaNNaNi`` outside the measured range), every 2nd
  frequency x every 2nd flux density, finite entries only, as a long table.
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import sys
import zipfile
from pathlib import Path

import h5py
import numpy as np

MATERIALS = {"N87": "TDK", "3C90": "Ferroxcube", "3E6": "Ferroxcube", "N49": "TDK"}
#: The wheel's other six materials: not vendored, written on request (``--others``) to check the loss
#: diagnosis on materials its settings were not chosen on (docs/diagnosis.md, "The rate series").
OTHERS = {"3C94": "Ferroxcube", "3F4": "Ferroxcube", "77": "Fair-Rite", "78": "Fair-Rite", "N27": "TDK", "N30": "TDK"}
WHEEL = "mag_net-0.1.0-py3-none-any.whl"
MAGNET_SOURCE = {"package": "mag-net", "version": "0.1.0", "index": "https://pypi.org/project/mag-net/0.1.0/",
                 "repository": "https://github.com/PrincetonUniversity/magnet",
                 "project": "https://mag-net.princeton.edu"}
MAGNET_LICENCE = {"name": "MIT", "copyright": "Copyright (c) 2021 Minjie Chen", "file": "LICENSE-MagNet.txt"}
LSF_SOURCE = {"repository": "https://github.com/otvam/large_signal_ferrite_apec24",
              "commit": "dd06889876ca7d360ae3c4cf6da6c507ba5fef2c", "folder": "dataset/N87_mu_large",
              "derived_from": "MagNet (Princeton University, Dartmouth College, Plexim GmbH), https://mag-net.princeton.edu"}
LSF_LICENCE = {"name": "MIT", "copyright": "Copyright (c) 2023 Thomas Guillod - Dartmouth College",
               "file": "LICENSE-large_signal_ferrite.txt"}


class _PlainData(pickle.Unpickler):
    """The store's metadata is a protocol-0 pickle of a dict of str/float/int: load no class."""

    def find_class(self, module: str, name: str):  # noqa: ANN201
        raise pickle.UnpicklingError(f"refusing {module}.{name}: the metadata should be plain data")


def _num(x: float) -> str:
    return repr(float(x))


def _write(out: Path, stem: str, header: str, rows: np.ndarray, sidecar: dict) -> None:
    lines = [header] + [",".join(_num(v) for v in row) for row in rows]
    (out / f"{stem}.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (out / f"{stem}.json").write_text(json.dumps(sidecar, indent=2) + "\n", encoding="utf-8")
    print(f"{stem}: {len(rows)} rows")


def convert_magnet(wheel: Path, out: Path, materials: dict[str, str] = MATERIALS) -> None:
    sha = hashlib.sha256(wheel.read_bytes()).hexdigest()
    out.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as zf:
        for mat, maker in materials.items():
            member = f"magnet/data/{mat}_database.h5"
            with h5py.File(io.BytesIO(zf.read(member)), "r") as h5:
                frame = h5["dataframe"]
                cols = [c.decode() for c in frame["block0_items"][:]]
                values = frame["block0_values"][:]
                meta = _PlainData(io.BytesIO(bytes(frame.attrs["metadata"]))).load()
            sine = values[:, cols.index("Duty_1")] == -1
            rows = values[sine][:, [cols.index("Frequency"), cols.index("Flux_Density"), cols.index("Power_Loss")]]
            sidecar = {
                "material": mat, "manufacturer": maker, "kind": "core_loss", "excitation": "sinusoidal",
                "source": {**MAGNET_SOURCE, "file": member, "wheel_sha256": sha},
                "licence": MAGNET_LICENCE,
                "units": {"frequency_Hz": "Hz", "flux_density_peak_T": "T", "loss_W_per_m3": "W/m^3"},
                "core_shape": meta["core_shape"], "effective_volume_m3": meta["effective_volume"],
                "effective_area_m2": meta["effective_area"], "effective_length_m": meta["effective_length"],
                "temperature_C": 25.0,
                "measured": f"{meta['info_date_sine']}; {meta['info_excitation']}",
                "trimmed": (f"the {int(sine.sum())} of {len(values)} rows with Duty_1 == -1 (sinusoidal "
                            "excitation); columns Frequency, Flux_Density, Power_Loss unchanged; Duty_1..4 and "
                            "Outlier_Factor dropped; no row removed (tests/data/real/convert_magnet.py)"),
            }
            _write(out, f"magnet_{mat}_sine", "frequency_Hz,flux_density_peak_T,loss_W_per_m3", rows, sidecar)
            _write_shapes(out, mat, maker, member, sha, cols, values, meta)


#: What MagNet's Duty_1..4 are, read from the wheel's own code (magnet/core.py, magnet/plots.py).
DUTY_MEANING = {
    "columns": "duty_1, duty_2, duty_3, duty_4: fractions of one period, in time order, of a piecewise-linear "
               "B(t): duty_1 rising (from -peak), duty_2 the first interval between the slopes, duty_3 falling, "
               "duty_4 the second interval between them (MagNet's d_P, d_0, d_N, d_0: duty_2 == duty_4 in every "
               "row); a triangle has duty_2 = duty_4 = 0 and duty_1 + duty_3 = 1",
    "waveform": "the winding sees a full bridge's +V, 0, -V, 0 over duty_1..duty_4 through a series capacitor "
                "that removes the mean, so the levels are 1 - (d1 - d3), -(d1 - d3), -1 - (d1 - d3), -(d1 - d3) "
                "(units of V): B is flat over duty_2 and duty_4 only when d1 == d3; its corners are -BP, BP, BN, -BN "
                "with BN = BP (1 + d1 - d3) d3 / ((1 - d1 + d3) d1), and the larger of BP, BN is the peak",
    "sine_marker": "duty_1 = -1 (all four -1) marks a sinusoidal row, MagNet's convention: those rows are in "
                   "magnet_{MAT}_sine.csv; no row here has it",
    "from_code": "mag-net 0.1.0 wheel: magnet/core.py core_loss_ML_triangular (inputs duty, 0, 1 - duty, 0) and "
                 "core_loss_ML_trapezoidal (inputs d_P, d_0, d_N, d_0 after log f and log B: the order of "
                 "Duty_1..4 the networks were trained on), core_loss_iGSE_trapezoidal (segment ends 0, d_P, "
                 "d_P + d_0, 1 - d_0, 1; corners -BP, BP, BN, -BN, -BP) and core_loss_iGSE_triangular (-flux, "
                 "flux, -flux at 0, duty, 1); magnet/plots.py cycle_points_trapezoidal (the voltage levels)",
    "rebuilt_by": "hystbench.formats.flux_shapes.shape_flux_density (period starting with the rising slope)",
}


def _write_shapes(out: Path, mat: str, maker: str, member: str, sha: str, cols: list[str], values: np.ndarray,
                  meta: dict) -> None:
    """The triangular/trapezoidal rows (Duty_1 != -1) of one store, as they are."""
    duty_cols = [cols.index(f"Duty_{k}") for k in range(1, 5)]
    shapes = values[:, duty_cols[0]] != -1
    rows = values[shapes][:, [cols.index("Frequency"), cols.index("Flux_Density"), *duty_cols,
                              cols.index("Power_Loss")]]
    tuples, counts = np.unique(rows[:, 2:6], axis=0, return_counts=True)
    sidecar = {
        "material": mat, "manufacturer": maker, "kind": "core_loss", "excitation": "triangular_trapezoidal",
        "source": {**MAGNET_SOURCE, "file": member, "wheel_sha256": sha},
        "licence": MAGNET_LICENCE,
        "units": {"frequency_Hz": "Hz", "flux_density_peak_T": "T", "duty_1": "1", "duty_2": "1", "duty_3": "1",
                  "duty_4": "1", "loss_W_per_m3": "W/m^3"},
        "flux_density_peak": "Flux_Density: the amplitude of B(t), half its peak-to-peak (magnet/core.py builds the "
                             "waveform between -flux and +flux)",
        "duty": DUTY_MEANING,
        "duty_tuples": {",".join(_num(v) for v in t): int(c) for t, c in zip(tuples, counts)},
        "core_shape": meta["core_shape"], "effective_volume_m3": meta["effective_volume"],
        "effective_area_m2": meta["effective_area"], "effective_length_m": meta["effective_length"],
        "temperature_C": 25.0,
        "measured": f"{meta['info_date_trap']}; {meta['info_excitation']}; {meta['info_setup_trap']}",
        "trimmed": (f"the {int(shapes.sum())} of {len(values)} rows with Duty_1 != -1 (triangular/trapezoidal "
                    "excitation); columns Frequency, Flux_Density, Duty_1..4, Power_Loss unchanged; Outlier_Factor "
                    "dropped (MagNet's per-row outlier score: its web app hides rows by it, magnet/io.py "
                    "load_dataframe; nothing is filtered here); no row removed (tests/data/real/convert_magnet.py)"),
    }
    _write(out, f"magnet_{mat}_shapes",
           "frequency_Hz,flux_density_peak_T,duty_1,duty_2,duty_3,duty_4,loss_W_per_m3", rows, sidecar)


def _matlab_complex(text: str) -> complex:
    text = text.strip()
    return complex("nan") if text.startswith("NaN") else complex(text.replace("i", "j"))


def convert_mu(folder: Path, out: Path) -> None:
    f = np.loadtxt(folder / "var_f_vec.csv", delimiter=",")
    b = np.loadtxt(folder / "var_B_mat.csv", delimiter=",")
    with open(folder / "var_mu_mat.csv", encoding="ascii") as fh:
        mu = np.array([[_matlab_complex(x) for x in line.split(",")] for line in fh if line.strip()])
    if not (b.shape == mu.shape == (f.size, b.shape[1]) and np.all(b == b[0])):
        raise SystemExit(f"{folder}: unexpected shapes f {f.shape} B {b.shape} mu {mu.shape}")
    fi, bi = np.arange(0, f.size, 2), np.arange(0, b.shape[1], 2)
    ff, bb = np.meshgrid(f[fi], b[0, bi], indexing="ij")
    mm = mu[np.ix_(fi, bi)]
    ok = np.isfinite(mm)
    rows = np.column_stack([ff[ok], bb[ok], mm[ok].real, mm[ok].imag])
    sha = {n: hashlib.sha256((folder / n).read_bytes()).hexdigest()
           for n in ("var_f_vec.csv", "var_B_mat.csv", "var_mu_mat.csv")}
    sidecar = {
        "material": "N87", "manufacturer": "TDK", "kind": "complex_permeability", "excitation": "sinusoidal",
        "source": {**LSF_SOURCE, "files_sha256": sha}, "licence": LSF_LICENCE,
        "units": {"frequency_Hz": "Hz", "flux_density_peak_T": "T", "mu_real": "1", "mu_imag": "1"},
        "convention": "relative permeability mu_r = mu_real + 1j * mu_imag for B = Re(B_pk exp(j 2 pi f t)); "
                      "mu_imag < 0 is loss (mu_r = mu' - j mu'')",
        "core_shape": "R22", "temperature_C": 25.0,
        "measured": "MagNet, derived by T. Guillod (Dartmouth College), IEEE APEC 2024",
        "trimmed": (f"every 2nd of {f.size} frequencies x every 2nd of {b.shape[1]} flux densities, the "
                    f"{int(ok.sum())} finite entries of {ok.size} (NaN outside the measured range); numbers "
                    "unchanged (tests/data/real/convert_magnet.py)"),
    }
    _write(out, "N87_mu_large", "frequency_Hz,flux_density_peak_T,mu_real,mu_imag", rows, sidecar)


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--others":  # convert_magnet.py --others WHEEL OUT
        convert_magnet(Path(sys.argv[2]), Path(sys.argv[3]), OTHERS)
        raise SystemExit(0)
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    convert_magnet(Path(sys.argv[1]), Path(sys.argv[3]))
    convert_mu(Path(sys.argv[2]), Path(sys.argv[3]))
