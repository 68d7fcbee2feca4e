"""Save ``coop``'s fallback-step inputs and stage maps on the Middlebury sets, to score fallback rules offline.

Usage::

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/coop_fallback_dump.py DIR
        [--sets 2014,v2,validation] [--scenes a,b]

For every scene ``coop_match`` runs with its defaults (``keep_stages=True``); the fallback step is wrapped so that
``DIR/<scene>.npz`` holds, besides the ground truth and masks (``gt``, ``m_nonocc``, ``m_all``, ``m_disc``) and
every stage map (``st_<step>``): the segments (``labels``), the map before the step (``final_in``) and the final
map (``out``), the masks the step reads (``nonplanar``, ``sparse``, ``evidence``, ``reliable``), the initial map,
BPASW's cross-checked map (``bdisp``, ``brel``), its dense map at every pixel (``bdense``, of the pair's own
volume also where the fallback takes an offset-compensated pair's map), its left-right check
(``bcheck``), its peak ratio at every pixel (``ratio``), ``sgm``'s map and check (``sgm``, ``sgm_valid``) and the
pair the steps read (``left``, ``right``); ``DIR/<scene>_bvol16.npy`` is BPASW's volume as float16. A rule for
the fallback can then be scored on all scenes in seconds (the bad-pixel rates of ``out`` are the matcher's).
Costs one extra ``sgm`` run's worth of dense maps per scene and ~0.1-0.2 GB of disk per 2014 scene.
"""

from __future__ import annotations

import argparse
import pathlib
import time
from typing import Any

import numpy as np

from prismstereo.evaluation.middlebury import list_scenes, load_scene
from prismstereo.matching.coop import coop_match
from prismstereo.matching.coop import pipeline as P
from prismstereo.matching.coop.flatcost import peak_ratio

ROOT = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"
SETS = {"2014": "middlebury-2014", "v2": "middlebury", "validation": "middlebury-extra"}


def _wrap(cap: dict[str, Any], folder: pathlib.Path) -> None:
    orig = P._PairEvidence.fallback

    def fallback(self: Any, s: Any, final: np.ndarray, p: Any) -> np.ndarray:
        sgm_map, sgm_valid = self._sgm_map()
        self._sgm_map = lambda: (sgm_map, sgm_valid)  # the step reuses this run
        out = orig(self, s, final, p)
        every = np.ones(final.shape, bool)
        cap.update(labels=s.labels.astype(np.int32), assign=s.assign, planes=s.planes, final_in=final.copy(),
                   nonplanar=self.nonplanar, sparse=self.sparse_segments(s, final, p), evidence=self.evidence,
                   initial=self.initial, reliable=self.reliable, bdisp=self.bdisp, brel=self.brel,
                   bdense=P.bpasw_dense_map(self.bvol, self.image, min_disp=self.min_disp, right_winner=self.bright,
                                            where=every, left_winner=self.bleft),
                   bcheck=self._bpasw_checked(), sgm=sgm_map, sgm_valid=sgm_valid,
                   ratio=peak_ratio(self.bvol, self.bleft, every), left=self.image, right=self.right)
        if self._fallback_right is not None:
            # the offset-compensated pair's BPASW evidence (the fallback's dense map reads its volume)
            vol = P.bpasw_volume(self.image, self._fallback_right, max_disp=self.max_disp, min_disp=self.min_disp)
            cl, cr = vol.argmin(axis=2), P.selection.right_winner(vol, min_disp=self.min_disp)
            md = self.min_disp
            cap.update(bdense_c=P.bpasw_dense_map(vol, self.image, min_disp=md, right_winner=cr, where=every,
                                                  left_winner=cl),
                       bcheck_c=np.asarray(P.selection.cross_check((cl + md).astype(np.float32),
                                                                   (cr + md).astype(np.float32), tolerance=1.0),
                                           bool),
                       ratio_c=peak_ratio(vol, cl, every), right_c=self._fallback_right)
        np.save(folder / f"{cap['name']}_bvol16.npy", self.bvol.astype(np.float16))
        return np.asarray(out)

    P._PairEvidence.fallback = fallback  # type: ignore[method-assign]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=pathlib.Path)
    ap.add_argument("--sets", default="2014,v2,validation")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (others skipped)")
    ap.add_argument("--root", default=str(ROOT), help="folder holding the three data sets")
    args = ap.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    want = {s.strip().lower() for s in args.scenes.split(",") if s.strip()}
    cap: dict[str, Any] = {}
    _wrap(cap, args.folder)
    for key in [s.strip() for s in args.sets.split(",") if s.strip()]:
        data = pathlib.Path(args.root) / SETS[key]
        for name in list_scenes(data):
            if want and name.lower() not in want:
                continue
            sc = load_scene(name, data)
            cap.clear()
            cap["name"] = name
            t, c = time.perf_counter(), time.process_time()
            r = coop_match(sc.left, sc.right, max_disp=sc.max_disp, keep_stages=True)
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            cap.pop("name")
            np.savez(args.folder / f"{name}.npz", set=key, gt=sc.gt, out=r.disparity,
                     **{f"m_{k}": v for k, v in sc.masks.items()}, **cap,
                     **{f"st_{k}": v for k, v in r.stages.items()})
            print(f"{name} ({key}): wall {wall:.1f} s, CPU {cpu:.1f} s", flush=True)


if __name__ == "__main__":
    main()
