"""The shipped elastomers (conf/material/<name>.yaml), fitted again from the Soft Robotics
Materials Database.

    git clone https://github.com/LucMarechal/Soft-Robotics-Materials-Database /tmp/srmd
    python experiments/fit_elastomers.py /tmp/srmd [--max-strain 1.5]

For each elastomer, every law nma.fit takes (Ogden with 2 and 3 terms) is fitted (nma.fit) to the
uniaxial engineering stress-strain curve of its tensile test up to `--max-strain`, and the stable
fit of least rms relative error is written to conf/material/<name>.yaml (its fit record names the
data, its sha256 and the errors).  A table of every law's errors is printed.  The database
(Marechal et al., Soft Robotics 8(3), 2021, doi 10.1089/soro.2019.0115) is licensed ODbL: nma
ships the fitted parameters, with this attribution, not the data.

The default range, engineering strain 1.5 (stretch 2.5), covers the stretches the reproductions'
states reach (metrics.json `stretch_range`) with room to spare, and stays below where the silicones
stiffen towards failure, which no two- or three-parameter law follows together with the small
strains.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# conf/material/<name> -> (the database's file, the product's name)
ELASTOMERS = {
    "ecoflex_0030": ("Ecoflex 00-30", "Ecoflex 00-30 (Smooth-On)"),
    "ecoflex_0050": ("Ecoflex 00-50", "Ecoflex 00-50 (Smooth-On)"),
    "dragon_skin_10": ("Dragon Skin 10 MEDIUM", "Dragon Skin 10 Medium (Smooth-On)"),
    "dragon_skin_30": ("Dragon Skin 30", "Dragon Skin 30 (Smooth-On)"),
}
# silicones keep their volume: nearly incompressible (the locking-free model, chosen by nu)
NU = 0.499


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("database", type=Path, help="a clone of the Soft Robotics Materials Database")
    ap.add_argument("--max-strain", type=float, default=1.5)
    ap.add_argument("--starts", type=int, default=16)
    args = ap.parse_args()
    from nma.errors import ConfigError
    from nma.fit import fit, write
    from nma.schema.commands import FIT_LAWS, FitConfig

    laws = {
        f"{law}{terms or ''}": (law, terms)
        for law in FIT_LAWS
        for terms in ((2, 3) if law == "ogden" else (None,))
    }  # label -> (law, Ogden's terms)

    commit = (
        subprocess.run(
            ["git", "-C", str(args.database), "rev-parse", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        or "unknown commit"
    )
    print(
        "| elastomer | law | rms relative error | largest | R^2 | stable |\n"
        "|---|---|---|---|---|---|"
    )
    for name, (file, product) in ELASTOMERS.items():
        data = args.database / "Tensile-Tests-Data" / f"{file}.csv"
        source = (
            f"Soft Robotics Materials Database (Marechal et al., Soft Robotics 8(3), 2021, doi "
            f"10.1089/soro.2019.0115; ODbL), Tensile-Tests-Data/{file}.csv at commit {commit}: "
            "uniaxial tension (ASTM D412), engineering strain and stress"
        )
        best = None
        for label, (law, terms) in laws.items():
            cfg = FitConfig(
                data=str(data),
                law=law,
                strain_column="Engineering Strain",
                stress_column="Engineering Stress (MPa)",
                max_strain=args.max_strain,
                nu=NU,
                unit="MPa",
                starts=args.starts,
                name=product,
                source=source,
                **({"terms": terms} if terms else {}),
            )
            try:
                material = fit(cfg)["material"]
            except ConfigError as err:
                print(f"| {product} | {label} | | | | no: {str(err)[:90]} |")
                continue
            r = material["fit"]
            print(
                f"| {product} | {label} | {r['rms_relative_error']:.4f} | "
                f"{r['max_relative_error']:.3f} | {r['r2']:.5f} | yes |"
            )
            if best is None or r["rms_relative_error"] < best["fit"]["rms_relative_error"]:
                best = material
        if best is None:
            sys.exit(f"{product}: no law fits stably")
        path = ROOT / "conf" / "material" / f"{name}.yaml"
        path.unlink(missing_ok=True)
        write(path, best)
        print(f"-> {path.relative_to(ROOT)}: {best['law']}")


if __name__ == "__main__":
    main()
