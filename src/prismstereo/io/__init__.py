"""Input and output at the edge of the library: images, PFM, PLY, JSON, TOML. All writes are atomic."""

from __future__ import annotations

from prismstereo.io.atomic import (
    atomic_path,
    atomic_write_bytes,
    atomic_write_text,
    check_output_dir,
    check_output_file,
    output_dir,
    output_files,
)
from prismstereo.io.images import read_image, write_image
from prismstereo.io.jsonio import library_versions, to_jsonable, write_json
from prismstereo.io.pfm import read_pfm, write_pfm
from prismstereo.io.ply import read_ply, write_ply

__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "library_versions",
    "check_output_dir",
    "check_output_file",
    "output_dir",
    "output_files",
    "read_image",
    "read_pfm",
    "read_ply",
    "to_jsonable",
    "write_image",
    "write_json",
    "write_pfm",
    "write_ply",
]
