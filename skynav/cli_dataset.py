"""``skynav dataset``: generate, verify, info, preview, export (thin wrappers over skynav.datasets)."""

from __future__ import annotations

from pathlib import Path

from skynav import datasets
from skynav.datasets.errors import OutputPathError, RecipeError
from skynav.datasets.frame_files import check_output_dir, check_stem
from skynav.datasets.recipes import PRESETS, read_recipe_mapping, recipe_yaml
from skynav.infra.atomic_files import atomic_write_bytes
from skynav.scenes.overrides import apply_overrides, keep_field_of_view

from .cli_args import (
    MAX_WORKERS,
    add_dask_arg,
    add_dataset_arg,
    add_output_arg,
    add_quiet,
    add_recipe_arg,
    add_seed_arg,
    add_set_arg,
    add_workers_arg,
    positive_int,
)
from .cli_common import COMMAND_HELP, EXIT_CHECK_FAILED, EXIT_OK, say


def recipe_from_args(arg: str, count, seed, overrides=()):
    """The recipe of a file or preset with the ``--set`` overrides, then ``--count`` and ``--seed``."""
    if arg not in datasets.PRESETS and not Path(arg).is_file():
        raise RecipeError("recipe", arg, "a recipe YAML file or a preset: " + ", ".join(datasets.PRESETS))
    recipe = read_recipe_mapping(arg)
    if overrides:
        before, recipe = recipe, apply_overrides(recipe, overrides)
        keep_field_of_view(before, recipe, overrides)  # a size override keeps the field (one line says so)
    recipe = datasets.validate_recipe(recipe)
    if count is not None:
        recipe["frames"] = count
    if seed is not None:
        recipe["seed"] = seed
    return recipe


def cmd_generate(args) -> int:
    recipe = recipe_from_args(args.recipe, args.count, args.seed, args.overrides)
    summary = datasets.generate(recipe, args.output, workers=args.workers, dask_scheduler=args.dask_scheduler,
                                progress=not args.quiet)

    say(args, *summary.lines())
    return 0


def cmd_recipe(args) -> int:
    text = recipe_yaml(args.preset)
    if args.output is None:
        print(text, end="")
        return 0
    out = Path(args.output)
    if out.is_dir():
        raise OutputPathError(f"{out}: -o/--output is a folder; give a file path such as {out / (args.preset + '.yaml')}")
    if out.exists() and not args.force:
        raise OutputPathError(f"{out}: exists; give another path, or --force to replace it")
    check_output_dir(out.parent if str(out.parent) else Path("."), what="-o/--output folder")

    atomic_write_bytes(out, text.encode())
    print(f"wrote {out}: the {args.preset} preset, every key commented; edit it, then: "
          f"skynav dataset generate {out} -o DATASET")
    return 0


def cmd_verify(args) -> int:
    report = datasets.verify(args.dataset, progress=not args.quiet)
    for line in report.lines():
        print(line)

    return EXIT_OK if report.ok else EXIT_CHECK_FAILED


def cmd_info(args) -> int:
    rows = datasets.info(args.dataset)["rows"]
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return 0


def _check_output_png(out: str) -> None:
    """Refuse a contact-sheet path that cannot be written (before reading the dataset)."""
    p = Path(out)
    if p.is_dir() or out.endswith("/"):
        raise OutputPathError(f"{out}: -o/--output is a folder; give a PNG file path")
    check_stem(p.name, what="-o/--output file name")
    check_output_dir(p.parent, what="-o/--output folder")


def cmd_preview(args) -> int:
    datasets.open(args.dataset)  # a missing or incomplete dataset is named first
    # by default in the current folder, named after the dataset: never a write into the input
    out = args.output or f"{Path(args.dataset).resolve().name or 'dataset'}_preview.png"
    _check_output_png(out)
    path = datasets.preview(args.dataset, out, count=args.count, columns=args.columns)
    print(f"contact sheet: {path} (a quick look of each frame: zscale limits and an asinh stretch, for the eye; "
          "circles: stars brighter than V 7, squares: the bodies in view, with their V magnitude)")
    if datasets.open(args.dataset).manifest["recipe"]["kind"] == "sequence":
        legs = datasets.leg_plot(args.dataset, Path(out).with_name(Path(out).stem + "_legs_vmag.png"))
        print(f"planets' V along the legs: {legs}")
    return 0


def cmd_export(args) -> int:
    if not args.webdataset:
        raise OutputPathError("dataset export: give the format of the export: --webdataset (tar shards)")
    # the shard writer loads on first use: skynav --help loads no room
    from skynav.datasets.shards import export_webdataset

    shards = export_webdataset(args.dataset, args.output, frames_per_shard=args.frames_per_shard)
    say(args, f"wrote {len(shards)} WebDataset shard(s) to {args.output} ({shards[0].name} .. {shards[-1].name}): "
              "per frame NNNNNN.dn.npy, NNNNNN.electrons.npy, NNNNNN.json")
    return 0


def add_parser(sub) -> None:
    d = sub.add_parser("dataset", help=COMMAND_HELP["dataset"],
                       description="Datasets: folders of frames (PNG/EXR) with ground truth, reproducible frame by frame.")
    dsub = d.add_subparsers(dest="dataset_command", metavar="ACTION")
    g = dsub.add_parser("generate", help="render a recipe into a dataset folder (resumes a partial one)",
                        description="Render a recipe (YAML file, or a preset: montecarlo, sequence, scenes) into a "
                        "dataset folder. Re-running the same command on a partly written folder renders only what is "
                        "missing. --set changes any key of the recipe before it is read, e.g. "
                        "--set render.cosmic_rays_per_frame=0 --set camera.width=256 --set camera.height=256; "
                        "'skynav dataset recipe PRESET -o FILE' writes a preset as a commented file to edit.")
    add_recipe_arg(g)
    add_output_arg(g, help="dataset folder")
    g.add_argument("--count", type=positive_int, default=None, help="number of frames (overrides the recipe)")
    add_seed_arg(g, default=None, help="master seed (overrides the recipe)")
    add_workers_arg(g, default=None, help=f"local worker processes, 1..{MAX_WORKERS} (default: all cores)")
    add_dask_arg(g)
    add_quiet(g)
    add_set_arg(g, "the recipe: kind-independent keys (camera.*, visibility.*, render.*, formats, ...) "
                        "and the kind's section (montecarlo.*, sequence.*, scenes.N.*)")
    g.set_defaults(func=cmd_generate)
    rc = dsub.add_parser("recipe", help="write a preset recipe as a commented YAML file to edit",
                         description="Write a preset recipe as a YAML file with a comment on every key (meaning, "
                         "unit, allowed values), including the visibility: and render: defaults. "
                         "'skynav dataset generate FILE -o DIR' reads it back: unedited, it makes the same dataset "
                         "as the preset.")
    rc.add_argument("preset", choices=tuple(PRESETS), help="preset: " + ", ".join(PRESETS))
    add_output_arg(rc, required=False, help="YAML file to write (default: print it)")
    rc.add_argument("--force", action="store_true", help="replace an existing file")
    rc.set_defaults(func=cmd_recipe)
    v = dsub.add_parser("verify", help="check checksums, schema and counts", description="Verify a dataset: "
                        "SHA-256 of every file, ground-truth schema, frame counts. Exit code 1 if a problem is found.")
    add_dataset_arg(v)
    add_quiet(v)
    v.set_defaults(func=cmd_verify)
    i = dsub.add_parser("info", help="print a summary table", description="Print a summary of a dataset.")
    add_dataset_arg(i)
    i.set_defaults(func=cmd_info)
    p = dsub.add_parser("preview", help="write a contact sheet PNG with ground-truth overlays",
                        description="Write a contact sheet PNG of a dataset with star circles and body labels; for a"
                                    " sequence, also the planets' V along the legs, next to the sheet: STEM_legs_vmag.png for"
                                    " -o STEM.png. The dataset is read only: the default sheet is NAME_preview.png in the"
                                    " current folder, NAME the dataset folder's.")
    add_dataset_arg(p)
    add_output_arg(p, required=False, help="PNG path (default: NAME_preview.png here, NAME the dataset folder's)")
    p.add_argument("--count", type=positive_int, default=16, help="frames on the sheet (default 16)")
    p.add_argument("--columns", type=positive_int, default=4, help="tiles per row (default 4)")
    p.set_defaults(func=cmd_preview)
    e = dsub.add_parser("export", help="write a dataset as WebDataset tar shards for training loaders",
                        description="Write a dataset as WebDataset tar shards (deterministic bytes): per frame the DN "
                        "and the float electrons as .npy and the truth JSON as it is, and the manifest beside them.")
    add_dataset_arg(e)
    e.add_argument("--webdataset", action="store_true", help="tar shards for the webdataset package")
    add_output_arg(e, help="folder of the shards (never inside the dataset)")
    e.add_argument("--frames-per-shard", type=positive_int, default=1000, metavar="N", help="frames per shard (default 1000)")
    add_quiet(e)
    e.set_defaults(func=cmd_export)
    d.set_defaults(func=lambda args: (d.print_help(), 2)[1])
