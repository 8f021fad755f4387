"""Localisation speed with few contacts, against the code of a baseline commit.

The README quick-start path (``ProximityModel(obj, 0.002, np.deg2rad(5))``,
``ScalingSeries(model, rng=seed).localize``), a hidden pose uniform in a 400 mm cube with
uniform rotation, k contacts with 2 mm / 5 deg noise. Two worker processes run the same
trials: one imports touchloc from this checkout, the other from a ``git archive`` of the
baseline commit. Trials alternate between the two, so both see the same machine load;
the table reports per-trial time ratios (baseline / current).

Run directly for one worker (``python benchmarks/bench_speed.py --worker``, reading JSON
trial requests on stdin) or through ``benchmarks/run.py --only speed``. The environment
variable ``TOUCHLOC_BENCH_THREADS`` sets the worker threads (numba; default: all cores);
``TOUCHLOC_BENCH_BASELINE`` another baseline commit (default: ``BASELINE``). A third
worker runs this checkout on one thread, for the speed-up that the threads give.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

TITLE = "Localisation speed with few contacts (vs. the baseline commit)"

BASELINE = os.environ.get("TOUCHLOC_BENCH_BASELINE", "f4e652e")
ROOT = Path(__file__).resolve().parent.parent
#: meshes whose profile guided the work, and meshes held out from it
TUNED = ["mug", "milk"]
STATUS = ('Where the goals stand (2026-12-01, AMD EPYC, two threads, load average 1.4; `ab_speed.py f4e652e --contacts 5,10,30 --meshes bread,cereal,milk,mug,lemon,can --trials 8`, this tree alternating trial by trial with f4e652e). Medians in seconds, this tree / f4e652e, and the median of the per-trial ratios:\n\n| mesh | 5 contacts | 10 contacts | 30 contacts |\n|---|---|---|---|\n| bread | 0.139 / 5.17 s, 38.3x | 0.074 / 0.92 s, 12.0x | 0.066 / 0.18 s, 2.66x |\n| cereal box | 0.144 / 10.67 s, 69.0x | 0.111 / 2.11 s, 16.8x | 0.077 / 0.24 s, 3.12x |\n| milk carton | 0.130 / 9.12 s, 71.9x | 0.096 / 1.75 s, 18.4x | 0.071 / 0.23 s, 2.91x |\n| mug | 0.153 / 13.68 s, 89.3x | 0.125 / 5.73 s, 49.2x | 0.094 / 0.52 s, 5.53x |\n| lemon | 0.074 / 6.85 s, 91.7x | 0.092 / 4.25 s, 44.8x | 0.141 / 0.67 s, 4.60x |\n| can | 0.158 / 6.16 s, 40.0x | 0.105 / 1.24 s, 12.0x | 0.103 / 0.28 s, 2.73x |\n\nA second run right after it (`--trials 12 --identify 12`: the first eight trials of each cell the same problems; load average 2.5 before and 1.3 after): at 30 contacts bread 2.41x, cereal box 2.42x, milk carton 2.74x, mug 4.43x, lemon 3.96x and can 2.44x (this tree 0.068-0.167 s); at 5 contacts 36-83x and at 10 10-49x (0.085-0.157 s); this tree\'s 95th percentile 1.1-1.8 times its median in every cell.\n\n- **Time:** under 1 / 0.5 / 0.2 s at 5 / 10 / 30 contacts on every mesh. The longest medians are 0.158, 0.140 and 0.167 s over both runs.\n- **Ratios:**\n  - 38-92x at 5 contacts and 12-49x at 10 (goals 10x and 5x).\n  - 2.66-5.53x at 30 contacts in the first run and 2.41-4.43x in the second (goal 3x). The mug and the lemon pass in both, and the cereal box in the first only. On this 2-core machine these ratios move by 0.3-0.7x between runs with the load (2.22-2.61x for the box-like meshes in the twelve-trial runs of 2026-11-30, below).\n  - The current tree ends with the posterior stage, which f4e652e does not have. Like for like, without it, the box-like meshes ran 3.0-3.4x (below).\n- **ADD-S < 5 mm:** 45 / 47 / 48 of 48 trials at 5 / 10 / 30 contacts in the first run, as many as f4e652e. In the second, 69 / 70 / 72 of 72 against f4e652e\'s 69 / 71 / 72; the one trial fewer at 10 contacts is the cereal box (10 / 12 against 11 / 12). This tree\'s four cereal-box misses at 5 and 10 contacts in that run are 6.8-13.5 mm off, and each answer\'s log-likelihood is 0.3-3.1 nats above the truth\'s: the contacts favour them, so they are not search failures.\n- **The likelihood:** `fast` against `exact` in the replay (the calls table below) is 4.4-5.8x on the mug and 6.5-8.6x on the can. On the bread, milk carton, cereal box and lemon it is 2.9-4.4x (goal 5x).\n- **Threads:** two give 1.34-1.38x over one. That puts the serial share of a localisation near a half, and Amdahl\'s law then projects 1.8-1.9x at 8 threads (goal 4x; the threads table at the end of this section). This cannot be measured on 2 cores.\n- **`identify` and the active loop:** `identify` takes 0.46 s median among six objects from 10 contacts (goal 2 s; 0.52 s, 12.7x f4e652e and 12 of 12 right in the second run). The active loop\'s update takes 0.051 s median (goal 0.2 s; section "Active loop: time per touch").')
NOTE = ('Where the time went at the baseline (cProfile of the mug at 5 contacts): about two '
        'thirds in the cover step, nearly all of it KD-tree ball counting; a tenth in the '
        'likelihood; a tenth in re-validating (4, 4) batches and converting rotations. Since '
        'then: the cover compares each draw only with the 2-delta neighbours of the ball it '
        'was drawn from, in a compiled loop, and keeps draws as quaternions until they are '
        'chosen (second table); Scaling Series scores its own particles without re-validating'
        ' them, and intermediate scales stop evaluating a particle once the prune is sure to '
        'drop it (last column of the second table); the nearest-face queries skip faces on '
        'their normal term alone (third table). The current tree also ends with the posterior '
        'stage (added after the baseline, on by default); its cost does not shrink with the '
        'cover, which is why the ratios with it are lower at 30 contacts than those with it off.'
        '\n\nProfile of the tree before the budgeted likelihood (process CPU time, one thread, '
        'one trial each): at 30 contacts (mug) the likelihood took 68 % of 1.8 s, the posterior '
        'stage 24 %, the cover 6 %; at 10 contacts (can) 68 %, 17 %, 12 % of 1.4 s; at 5 '
        'contacts (milk, mug) the cover 45-52 % and the likelihood 38-48 % of 3-5 s. At 5 '
        'contacts the particle cap (20000) binds for the last 20 of about 40 scales and 30 % '
        'of those particles survive the prune; inside the cover, the KD-tree pair query for '
        'the neighbour lists, the draws with their quaternion algebra and the count kernel '
        'take about a third each. Early scales are dominated by queries far from the object '
        '(0.3-0.4 M pairs/s on one thread against 0.8 near it). The step since then: the '
        'likelihood of a batch of poses is one compiled pass (contacts moved into each '
        'frame inside it), and at intermediate scales each particle gets, after a first '
        'quarter of its contacts, the budget that the prune leaves it: its remaining '
        'contacts are scored one by one until the budget is spent, and each nearest-face '
        'search starts with the remaining budget as its bound, so the search under a far '
        'or wrongly turned contact ends at the root. The prune keeps exactly the particles '
        'and weights of a complete evaluation (tested). In CPU time on one thread this cut '
        'the likelihood share by 1.1-1.6x (mug 30 contacts 1.21 to 0.74 s, can 10 0.95 to '
        '0.67 s, milk 5 1.14 to 0.89 s, mug 5 2.37 to 2.15 s). `identify` no longer runs '
        'the posterior stage when no beliefs are asked for (its answer comes from the last '
        'cover): about a quarter of its time. Tried and dropped: counting the cover\'s '
        'draws in random order only until the cap is filled (slower: the neighbour lists are'
        ' built again per round and the draws lose their memory locality), warm-starting the'
        ' exact search from the fast grid\'s answer (no faster: the tree descent dominates),'
        ' and stopping hopeless candidates early in `identify` (a rule on the annealed '
        'evidence named the mug for a can, whose good poses are few at high temperature; a '
        'sound bound on the best cost triggers only in the last scales and saved under '
        '10 %; a lighter evidence budget, 3 particles per neighbourhood instead of 4, was '
        '1.3x faster at 10 contacts, 1.36 against 1.77 s median over 30 trials, but made 2 '
        'mistakes in the identification benchmark\'s 72 trials against none). The particle cap per scale is now 6000 (was 20000): on held-out trials it '
        'cut 5-contact CPU time 2.2x with 38 of 42 localised against 36 of 42, and was level '
        'at 10 and 30 contacts (section "Scaling Series\' particle cap"); it accounts for '
        'most of the step from the earlier rows of this table to these.'
        ' Against the tree just before this step (commit 666723a, `TOUCHLOC_BENCH_BASELINE=666723a python benchmarks/bench_speed.py --quick`, same workers, load average 11-22 on 2 cores): mug 1.4x at 5 and at 10 contacts, 1.1x at 30, can 1.1x at 10 contacts, `identify` 1.6x.'
        '\n\nA step before: calls below 4096 pose-contact pairs run a one-thread kernel (the '
        'thread pool waits for a time slice on a loaded machine: with one busy process on the '
        'other core, 1000 pairs took 8 ms on two threads against 0.9 ms on one). That kernel, '
        'compiled without numba\'s parallel pipeline, ran the same loop 2.1x slower than the '
        'parallel kernel on one thread (400 mug poses x 10 contacts: 8.3 against 3.7 ms); it is '
        'now compiled with the pipeline over a plain `range` (4.0 ms). In `identify` these calls '
        'took a third of the time. Against the tree just before this step (commit 21b6239, '
        '`TOUCHLOC_BENCH_BASELINE=21b6239 python benchmarks/bench_speed.py`, load average 1.5): '
        '`identify` 1.1-1.2x on all six objects (median 1.53 s, longest 1.94 s, against 1.78 and '
        '2.14 s), localisation 1.0-1.4x (median of per-trial ratios per row), 1.1-2.1x with the '
        'posterior stage off.'
        '\n\nThe step after it, found by timing every likelihood call of three mug localisations by '
        'method and size: at 30 contacts half of the time (0.49 of 0.97 s) went to 215 calls '
        'under 20,000 pose-contact pairs, which `auto` sent to the exact tree; these were the '
        'posterior stage\'s 500 poses x 30 contacts. The fast grid\'s far-off contacts (the '
        'first scales) also went to the tree, at 1.0x exact. Three changes: (1) `auto` uses the '
        'grid from 2,000 pairs (at 30 contacts the three localisations took 0.55 s instead of '
        '0.97 s); (2) two coarser grid levels (cells 4x and 16x, reaching 2 and 8 extents beyond '
        'the mesh) list those far-off contacts: far queries 1.0x to about 4x exact, with errors '
        'under 1 % of the cost at the 99th percentile; (3) every nearest-face search skips a face '
        'whose plane distance plus normal term already exceeds the best cost, and a cell\'s list '
        'is scanned best first (one thread, mug near the truth: 3.1 to 3.5 M pairs/s; lemon 0.9 to '
        '1.1). Against the tree just before this step (commit a5ba0fd, '
        '`TOUCHLOC_BENCH_BASELINE=a5ba0fd python benchmarks/bench_speed.py`, load average 1.6): '
        'localisation 1.1-2.1x (mug 0.67 / 0.45 / 0.20 s at 5 / 10 / 30 contacts, against 1.04 / '
        '0.62 / 0.31 s; 2.3-2.5x at 30 contacts with the posterior stage off), every trial still '
        'within 5 mm; `identify` 1.5-1.7x on all six objects (median 0.96 s, longest 1.28 s, '
        'against 1.48 and 1.89 s). Tried and not kept: a list per cell and normal bin (a cube map '
        'of 96 bins, winners sampled at the cell\'s corners): 4.4 faces per list instead of 20 and '
        'a maximum error of 9 instead of 90 on the mug, but only 1.2x faster with the descent, '
        'and 85-200 MB per mesh, against 9 MB; and each cell\'s list sorted by the cube-map bin '
        'of its faces\' own normals, so that a query skips a whole bin by angle: slower (one '
        'thread, lemon 1.1 to 0.8 M pairs/s, mug 3.5 to 2.7). On the lemon about 9 faces per '
        'query pass the bound and need their closest point, and walking the bins costs more '
        'than the bounds it saves. Measured since and not kept (one thread; the object-frame queries of 500 poses within about 3 deg / 3 mm of the truth, times 30 contacts): on the mug a query evaluates about 19 bounds over its cell\'s list, 14 over the faces around the winner in the descent and 3 closest points, so neither bounds read from per-entry plane arrays nor a second bound from each face\'s bounding sphere changed its time (1.0x). The winners of the 4 sampled normals nearest to the query\'s (a cube map of 384 bins), followed by a descent over edge-adjacent faces only, were 1.5-2.3x faster than the shipped grid (mug 281 to 168 ns per pair, lemon 700 to 303) but off by more than a tenth of a squared sigma on 10-13 % of the lemon\'s pairs (0-0.2 % shipped). A five-fold likelihood needs another representation, not a leaner list.'
        '\n\nThen: a near-spherical object (the ball row) has no preferred orientation,'
        ' and the cover filled the particle cap with turned copies of the right answer at every '
        'scale (160 thousand likelihood evaluations, 13.5 s at 10 contacts at the baseline). '
        'Scaling Series now finds the sphere\'s symmetry by testing the mesh and keeps one pose '
        'per class (the identity rotation, the surface centre kept in place): about 3 thousand '
        'evaluations. The same search for a body of revolution (can, lemon) saved a third to a '
        'half of the evaluations but was no faster (its representatives crowd one slice of the '
        'pose space, and the cover\'s counting there rose): it is off by default for them.'
        '\n\nThe latest step, from a profile of milk and mug at 30 contacts (one thread; the posterior stage took 43 % of the milk\'s time, a third of it in the tempering\'s bisection on its power, 30 evaluations of the effective sample size per stage through scipy\'s logsumexp, and a tenth in re-validating the estimator\'s own poses): the ESS is now plain numpy, the moves are scored through the model\'s unvalidated cost pass, and the per-scale beliefs skip re-checking their rotations (the weights are still checked). Then, from a profile of the mug at 5 and 10 contacts (the cover half of the time at 5, a quarter of it in building the draws): the draws of full rotations (direction, radius, exp map, product with the centre, sign, embedding) are one compiled pass over numpy\'s random numbers. Against the commit before each (`python benchmarks/ab_speed.py REV`, 6 trials per cell, alternating): 1.09 / 1.18 / 1.12 / 1.13x at 30 contacts (mug, milk, can, cereal) and 0.99-1.07x at 10 for the first; 1.08 / 1.15 / 1.09x at 5 contacts and 1.11 / 1.13 / 1.07x at 10 (mug, milk, lemon) for the second. What is left at 5 contacts (mug, one thread): the cover 51 % (the KD-tree pair query of its neighbour lists 17 %, the draws 15 %, the counts 7 %), the likelihood 44 %. Since then, from the same kind of profile at 30 contacts (mug: 573 of 862 likelihood calls, 0.5 of 1.9 s, ran on one thread, being under 4096 pose-contact pairs): calls of 512 to 4096 pairs now run on one thread or in parallel by the two versions\' measured time per pair (an exponential average; every 64th call runs the slower one to notice a change of load). The two versions compute every row alike, so the results are unchanged. Against the commit before (`python benchmarks/ab_speed.py HEAD --contacts 5,10,30`, 6 trials per cell, alternating, load average 1.5-1.8): 1.15 / 1.09 / 1.25 / 0.99x at 30 contacts (mug, milk, can, cereal), 1.01-1.04x at 10 and 1.00-1.02x at 5. A fixed threshold of 512 instead was 1.16-1.27x at 30 contacts on an idle machine but 0.67-0.99x with one busy process on the other core (the parallel region waits for a thread that shares its core: 2.3-4.5 us per pair against 0.4-1.8 on one thread); the measured choice was 0.94-1.05x there.'
        '\n\nThe steps after 2505e99, from profiles of the milk carton at 30 contacts and the mug at 10. '
        '(1) The posterior stage\'s moves and the cover stopped re-checking poses they made themselves: '
        'the region\'s perturbation and membership test on trusted poses, subsets of contacts without '
        're-validation, scipy\'s rotation checks skipped for matrices already checked (they cost 13 times '
        'the conversion of 6000 rotations); the draws\' region test, the flipped copies\' distance test and '
        'the draws themselves in compiled loops, the draws on the thread pool from 4096. Results bit-identical; '
        '1.07-1.17x (`ab_speed.py 2505e99`, 8 trials per cell, mug, milk, bread and can at 5, 10 and 30 '
        'contacts). (2) Where the particle cap binds the cover drew every candidate and thinned most away (the '
        'mug at 10 contacts: 7,000-17,000 kept per scale for 6,000 or fewer used). It now draws in batches of '
        'whole rounds over the centres, sized at the acceptance rate measured so far (at first the previous '
        'scale\'s) to fill the cap with a fifth to spare, and the batches share one set of neighbour lists. The '
        'same distribution (tested against the reference cover), another random stream. With (1): 1.06-1.24x '
        'against 2505e99 over 180 paired trials (mug, milk, bread, can, cereal, lemon at 5, 10 and 30 contacts, '
        '10 trials each), 177 within 5 mm against 176. (3) Lower bounds of every pair from a table per mesh '
        '(docs/localization.md, "Pruning on lower bounds"): a particle stops once its costs so far plus the '
        'bounds of its other contacts pass the prune threshold. Simulated on the mug at 10 contacts, the exact '
        'pairs evaluated fell to 63 % (about half at the middle scales, 0.9 at the last ones); the lookups cost '
        'about 20 ns per pair. Measured against the commit before (`ab_speed.py HEAD`, 8 trials per cell): '
        '1.01-1.19x (mug 1.06 / 1.13 / 1.19x at 5 / 10 / 30 contacts), results bit-identical on the trials '
        'checked. A finer table (16 cells per extent and 96 bins instead of 12 and 54) was level within the '
        'noise (1.01-1.26x) and took three times as long to build (1.5-2.9 s per mesh). Accuracy after all three, paired on the localisation benchmark\'s seeds (1000-1019; bread, milk, mug, can, cereal and lemon at 10 and 30 contacts, 240 trials) against 2505e99: the same 239 of 240 within 5 mm, median ADD-S per cell between 0.6 mm lower (bread, 30 contacts: 1.29 to 0.69 mm) and 0.06 mm higher. (4) The posterior stage\'s Metropolis moves draw their uniform first: a proposal is accepted only if its cost is below what that draw allows, so each proposal stops as soon as its costs reach that, and is rejected (30-40 % of the proposals on the milk carton and the mug at 30 contacts). The same moves, bit for bit (tested); 1.17x on the milk carton at 30 contacts, 0.97-1.04x elsewhere (`ab_speed.py HEAD`, 8 trials per cell, milk, bread, mug, can at 5, 10 and 30 contacts). (5) The cover\'s rotation conversions, which paid scipy\'s overhead on every call, are now compiled passes that repeat scipy\'s arithmetic in its order: the centres\' matrices to quaternions and the kept draws\' quaternions to poses (the same numbers bit for bit, tested; a hash of ten localisations unchanged). A few per cent: 1.01-1.15x over mug, milk and bread at 10 and 30 contacts for the second alone (`ab_speed.py HEAD`, 8 trials per cell), 0.95-1.08x, median 1.04x, for both against 362c999 (10 trials per cell, the can added), about the size of the load\'s effect on one cell (the same 2 cores; load average 1.0 before and 1.3 after the first run). (6) A cell list\'s bounds were computed twice per query (once to find the face that leads, once to skip the others); the first pass now keeps them in a scratch row per numba thread (`CandidateGrid.scratch`, as wide as the longest list). The same faces are evaluated, bit for bit. On one thread, 60,000 queries of poses within 1 cm / 0.1 rad of the truth at 30 contacts: mug 1.29 to 1.61, lemon 0.48 to 0.64, milk 2.95 to 3.37 M pairs/s. Counted on the same queries, a query reads 18.5 (mug), 56 (lemon) and 6.5 (milk) list entries, 14-17 bounds of faces around the winner in the descent, and 3.2-17.5 closest points (mug 6.2); a third bound from each face\'s bounding sphere cut the closest points to 4.3 / 7.5 / 2.4 but its square root made every mesh 1.05-1.4x slower. The posterior stage also scores each distinct pose of a cover smaller than its sample once (the cover is subsampled with repeats; the method is the one a pass over the whole sample would use): bit for bit the same. Against the commit before (`ab_speed.py HEAD~1 --contacts 30,10`, 8 trials per cell, load average 1.6-1.8): 1.01-1.09x at 30 contacts (milk 1.05, bread 1.09, mug 1.04, cereal 1.01, can 1.08x) and 0.99-1.07x at 10. (7) The posterior stage\'s tempering, profiled at 30 contacts (bread, 12 localisations, one thread), spent 0.14 s outside its likelihood against 0.40 s in it: the spread of the particles (`_scale`, 0.86 ms a call, a third of it re-checking the belief\'s own poses in `to_local`), scipy\'s `logsumexp` (0.17 ms a call, three per stage) and the moves\' perturbation. A belief\'s tangent coordinates no longer re-check its own poses (a reference given by the caller still is), and the tempering\'s log-sum-exp repeats scipy\'s arithmetic in plain numpy (equal bit for bit, tested on 3000 arrays with ties and -inf). Against the commit before (`ab_speed.py HEAD --contacts 30,10`, 8 trials per cell, load average 1.0-1.4): 1.04-1.09x at 30 contacts (milk 1.09, bread 1.04, mug 1.06, can 1.04x), 1.00-1.05x at 10; a hash of 12 localisations unchanged. The table\'s 30-contact rows rest on 2-3 trials; twelve trials per mesh against the baseline (`ab_speed.py f4e652e --contacts 30 --trials 12`, seeds 8000-8011, load average 0.9-1.3) give milk 2.80x, bread 2.05x, cereal 2.73x, mug 4.38x and can 2.44x (medians 0.072-0.114 s against 0.160-0.476 s): with the posterior stage, which the baseline did not have, the goal of 3x at 30 contacts is met on the mug only.'
        ' Those figures predate c4304ab, whose temperature schedule keeps more particles with many contacts s'
        'o that the prune does not drop the true mode (section "Scaling Series\' annealing with many contacts'
        '"). On the mug at 30 contacts (seed 8001, 2 threads, an idle machine, 2026-11-29) the commit before '
        'it evaluates 15,077 poses, c4304ab 54,254, and the current tree, after the changes since (the particle cap among them), 39,791'
        ': 0.73 s a localisation, against 0.33 s for d9bfce1 on the same machine the same day.'
        '\n\nThen the fast likelihood near the surface (docs/localization.md, "Measurement models"): the '
        'finest level\'s cells within three cells of the surface keep, per normal bin of a cube map (384 '
        'bins), the faces that win at their corners for the bin\'s centre, corners and edge midpoints '
        '(1.6-3.8 faces a list on the bundled meshes), scanned with a bound that is the cost itself where the '
        'point projects into the triangle, and no walk; a mesh keeps them only where their own check against '
        'the exact method at build finds them no less accurate than the general lists (or within 1 % of '
        'answers off by 0.1 d_M^2; the cereal box and a 10,000-face torus drop them). One thread, queries of '
        'poses within 2 mm / 0.02 rad of the truth at 30 contacts (ns a query, before / after, exact): '
        'lemon 526 / 250 / 668, mug 202 / 82 / 397, milk 140 / 56 / 226, bread 133 / 70 / 240, can 213 / 106 / '
        '1123, bunny 198 / 94 / 456. Against the commit before (`ab_speed.py HEAD~1 --contacts 5,10,30`, 10 '
        'trials per cell, six meshes): 1.10-1.38x at 30 contacts (mug 1.18, milk 1.10, lemon 1.38, bread '
        '1.11, can 1.16x; the cereal box, which keeps no near lists, 0.97x), 0.98-1.18x at 10 and 0.98-1.07x '
        'at 5; 176 of 180 within 5 mm against 177 (one milk trial at 5 contacts), and on 40 paired '
        'trials per mesh at 5 contacts (mug, milk, lemon, bread, seeds 7000-7039) 153 of 160 against 154.'
        ' Twelve trials per mesh against the baseline at 30 contacts (`ab_speed.py f4e652e --contacts 30 --trials 12`, the seeds above, load average 0.1-1.1): milk 3.15x, bread 2.44x, cereal 2.88x, mug 4.78x, can 2.86x (medians 0.063-0.100 s against 0.155-0.474 s, all 60 within 5 mm): with the posterior stage, the goal of 3x at 30 contacts is now met on the milk carton and the mug.'
        '\n\nThen flat sides split into triangles (docs/localization.md, "Measurement models"): the near lists missed long slivers that cross a cell between its corners, and on the cereal box the check dropped its lists for that (1.27 % of its queries off by more than 0.1 d_M^2, against 0.75 % for the general lists). A list now also holds each winner\'s coplanar faces that come within half a cell diagonal of the cell\'s centre projected on their plane. Off in the build\'s check: cereal 1.27 % to 0 (lists kept), can 1.36 % to 0.01 %, mug 0.41 % to 0.005 %, milk 0.25 % to 0, bread 0.22 % to 0; the lemon, which has no coplanar faces, unchanged. Against the commit before (`ab_speed.py HEAD~1`, load average 1.2-1.6): 8 trials per cell at 5 / 10 / 30 contacts, cereal 1.02 / 1.13 / 1.15x, milk 1.06 / 0.96 / 1.08x, bread 1.01 / 1.05 / 1.01x, can 0.88 / 1.05 / 0.94x, mug 1.05 / 1.04 / 0.89x; then 12 trials per cell at 5 / 30 contacts, mug 1.00 / 1.00x, can 0.96 / 1.00x, cereal 1.02 / 1.17x; 186 of 192 trials within 5 mm against 187 (the cells differ by one trial each way). Twelve trials per mesh against the baseline at 30 contacts in the same way as above (`ab_speed.py f4e652e --contacts 30 --trials 12`, load average 1.6, a slower day: medians 0.109-0.249 s against 0.336-0.985 s): cereal 3.61x, bread 2.67x, can 3.01x, milk 3.94x, mug 4.12x, all 60 within 5 mm. The goal of 3x at 30 contacts is met on four of the five meshes; the bread stays below it. The machines these runs share differ (an Intel Xeon about half as fast as an AMD EPYC: the baseline\'s mug at 5 contacts 30.4 s against 13.9 s), so compare ratios, not seconds, between runs; the tables say which machine.'
        "\n\nTried since and not kept: the pose-cost kernels walking blocks of 32 poses contact by contact instead of pose by pose (each pose's arithmetic unchanged). On one thread, 60,000 queries of 2000 poses within 2 mm / 0.02 rad of the truth at 30 contacts ran 1.1-2.0x faster in that order (fast: lemon 789 to 392 ns a query, mug 223 to 186, milk 161 to 137, bread 209 to 169, can 283 to 253; the lemon's near lists take 16 MB, the others' 2-10 MB, so a query pose by pose misses the cache). In localisation it did not pay: against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes mug,milk,lemon,bread,can,cereal --trials 8`, load average 1.3-1.4) 0.86-1.09x, 0.86-1.05x at 30 contacts (lemon 0.94x), the same trials within 5 mm. The particles a localisation scores come in no spatial order (the cover's draws go round its centres), so neighbouring poses in a block seldom share cells."
        '\n\nAlso tried and not kept (2026-11-28, AMD EPYC): at intermediate scales with more than 15 contacts, scoring each scale\'s particles on a fresh random subset of ceil(K / g) contacts at Alg. 1\'s temperature instead of all K at the "auto" schedule\'s g times it (the same annealed information, in expectation, at a fraction of the pairs; the last scale and the posterior stage on every contact). At 30 contacts it was 1.11-1.29x faster (`ab_speed.py HEAD --contacts 30 --meshes mug,milk,bread,can,cereal --trials 8`; mug 0.414 to 0.298 s, every trial within 5 mm either way) with no search failures on 48 new 6-DOF trials (`study_anneal.py --region cube --contacts 30 --trials 8 --offset 700 --schedules auto`) or 120 planar ones (`--contacts 30 60 --trials 12 --offset 300`: 1 and 3 against 2 and 3), but the truth fell in the 90 % region in 73 % of the 6-DOF trials against 83 %: the subsets\' noise prunes some of the posterior\'s support before the last scale.'
        "\n\nMeasured and not kept as well: the cover's neighbour lists from a compiled brute-force scan instead of the KD-tree's pair query (partial squared distances with an early exit, the coordinates taken in order of their spread, two passes straight into the lists). On the centres of one mug localisation at 10 contacts (AMD EPYC; 1,200-1,840 centres with 8-56 neighbours each) it took 16-53 ms on one thread and 8-27 ms on two, against 1.4-4.3 ms for the pair query and its lists (best of three): the KD-tree stays. The pair queries take about 96 ms of that 0.6 s localisation, over its 41 scales."
        "\n\nWhere the fast method's time goes now, on the pairs that localisations ask for (`study_fast_anatomy.py`, 2026-11-30, AMD EPYC, one thread: the calls of four localisations per row replayed, and the queries of every third call split by what the fast method does with them). On the bread, milk carton, cereal box and mug, 71-86 % of the queries find a near list: 62-141 ns a query, against 289-863 ns exact. Another 14-24 % fall in a finest-level cell whose normal bin has no list. These are contacts turned away from every face near them, and they scan the cell's general list: 213-558 ns, against 493-2606 exact. They take 35-55 % of the fast method's time on those meshes (per query times its share). The lemon's queries are 97-99 % near-listed but cost 207 ns (858 exact): its near lists take 16 MB, and the same queries sorted by cell take 129-141 ns. On the other meshes sorting by cell saves 19-71 ns of 62-130. A near-listed query makes two dependent loads (its cell's record, then its list's entry), and a miss on each is most of its cost. Replayed whole: fast / exact 2.49 / 2.74x (bread, 10 / 30 contacts), milk 3.10 / 3.58x, cereal 2.83 / 3.94x, lemon 3.43 / 3.72x, mug 4.38 / 4.64x."
        "\n\nTwo attempts on that were measured and not kept. (1) Each call's poses sorted along a Morton curve of the contacts' centroid in their frames, so that neighbouring poses share cells: 0.87-1.07x on the same replays, and 1.12x on the bread at 10 contacts in a rerun beside another job: no steady gain (`study_fast_anatomy.py`, second figure of each row). (2) The list search started from the pair's remaining budget instead of from infinity, so that a contact sure to spend it skips its faces' closest points and the descent (a one-line change in `_pair_cost`). Replayed on one thread it was 1.01-1.13x faster: bread 10 contacts 24.2 to 21.8 ms, mug 46.5 to 41.1, lemon 52.2 to 47.2, milk 32.0 to 30.3, cereal 26.8 to 26.4, bread 30 contacts 34.4 to 33.3. But it changed which rows stop in 8 of 807,029: a list whose faces all cost more than the budget can still descend to a face below it. So a row stopped where the complete fast answer goes on, and the budget would no longer leave the prune's choice as it is. What the 5x goal on the box-like meshes needs is to make the general-list queries cheap. A rigorous lower bound per finest cell and normal bin, tight enough to exceed a row's remaining budget, would stop them before any face. The bound table's cells are too coarse for that (a twelfth of the extent: the bread's slack is 18 mm), and a table at the finest cells with 384 bins would take 37 MB on the bread. Not built."
        "\n\nThe cover's neighbour lists from a compiled grid hash instead of the KD-tree's pair query (cells of 2 r on the three coordinates of widest spread, the other four checked with an early exit) took 3.1x the pair query's time, its tree's build included: 327 against 104 ms on the 56 centre sets of two mug localisations at 5 contacts (one thread). The KD-tree stays. At 5 contacts the pair query is now the largest serial part of a mug localisation: about 28 % of 0.16 s (cProfile, two threads)."
        "\n\nThen Scaling Series' temperature schedule (docs/localization.md, \"Many contacts: the annealing schedule\"): beyond 15 contacts the annealed posterior is now kept as wide as at 15 (`anneal='auto'`, tau = (k / 15) (delta / delta*)^2), because Alg. 1's schedule returned a wrong mode, 5 nats or more below the truth's log-likelihood, in 10 of 48 held-out 6-DOF trials at 30 contacts (bread 3, milk 3, mug 2, can 2), which ADD-S < 5 mm did not notice. It costs time at 30 contacts and nothing up to 15 (the same code path): against the commit before (`ab_speed.py HEAD~2 --contacts 30,10 --trials 6`, six meshes, load average 2.1 before and 1.7 after), 0.32-0.64x at 30 contacts (mug 0.36, bread 0.64, can 0.44, lemon 0.32, milk 0.55, cereal 0.55x) and 0.93-1.18x at 10; every trial within 5 mm with either. The speed goals at 30 contacts (0.2 s and 3x the baseline) had been met partly by a search that failed on a fifth of the trials; the table's 30-contact rows are now those of a search that finds the right mode."
        "\n\nThen the particle cap per scale from 6000 to 3000, with the draws per scale capped apart at 24000, as 6000's budget was (`max_draws`; section \"Scaling Series' particle cap\": at 4 x 3000 draws a planar mug at 30 contacts lost its handle in 4 of 12 trials). On 84 held-out trials per contact count (seeds 19-30, seven meshes, CPU time on one thread) it was 1.70x / 1.22x / 1.03x faster at 5 / 10 / 30 contacts (the mug 1.79x / 1.45x / 1.21x), with the same trials localised (78 / 84 / 84) and the truth in the 90 % credible region as often (76 / 73 / 77 against 77 / 70 / 77). The tables above are measured with it."
        "\n\nThen `auto` resolved once per Scaling Series run (by its largest batch, so always the grid with the default caps) instead of per call. Timing every likelihood call of the ball at 30 contacts (one thread) found its late scales, a few dozen representatives each (the symmetry leaves only the position), on the exact tree at 5.4-9.2 us a pair, since they fell under the 2,000 pairs from which `auto` uses the grid; the grid, built by the first scale in any case, takes 0.3-0.4 us a pair there. Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes ball,mug,milk,lemon,can --trials 8`, load average 0.6 before and 1.8 after): the ball 1.40 / 1.34 / 1.52x at 5 / 10 / 30 contacts (0.279 to 0.176 s at 30), the others 0.97-1.10x, every trial within 5 mm either way."
        "\n\nThen the cover's first scale, profiled (mug, one thread): the union of some 1,400-2,000 balls as wide as the region, from which the cover keeps about five draws, took 42-47 ms, two thirds of it in KD-tree counts of every draw that saturated the capped count (16 balls), each counting nearly all the centres. Such draws are now counted again capped at 16 times the cap, and kept with probability cap / that count, before any full count (each draw is still kept with probability 1 / count; tested at two caps); the counting plan's probe reads its distances from one matrix product instead of 128 tree queries. That cover takes 23 ms. Against the commit before (`ab_speed.py 97b8995 --contacts 5,10,30 --meshes mug,milk,can,lemon --trials 8`, load average 1.4-1.8): 1.04-1.09x at 5 contacts, 0.99-1.09x at 10 and 0.98-1.07x at 30, every trial within 5 mm either way; `identify` (six objects, 10 contacts, 18 trials alternating with that commit) 1.08x, median 1.50 s (longest 2.34 s) against 1.64 s (2.69 s), all 18 right with either. Another random stream: on the planar mug at 30 contacts the handle was lost in 17 of 280 runs against 14 of 280 before."
        "\n\nThen a floor of 50 particles on every scale's cover (`min_particles`, docs/localization.md, \"Many contacts: the annealing schedule\"): a planar mug at 30 contacts had lost its handle in 17 of 280 runs because the first covers of a small region held 1-10 particles; with the floor in 1 of 280. Its price, against the commit before (`ab_speed.py ac2869e --contacts 5,10,30 --meshes mug,milk,can,lemon --trials 6`, load average 2.9 before and 1.7 after): 0.84-1.05x, median 0.96x, every trial within 5 mm either way; `identify` 0.91x (18 trials, median 1.41 s against 1.30 s, all right with either). The tables above are measured with it."
        "\n\n" + 'Then the wide scales scored on the bound table (`bound_scales`, docs/localization.md, "Wide scales scored on the table"). A per-scale trace of the mug at 30 contacts (seed 8001, 2 threads) showed where the annealing gain of c4304ab had put the time: scales 16-23 (delta 68-30 mm, tau 570-110) each filled the particle cap (3,000) and took 24-41 ms, 260 of 560 ms; Alg. 1\'s schedule had 200-2,000 particles there. At those temperatures a contact\'s cost needs no closer reading than the table\'s slack (10-15 mm), so such scales now read the bounds alone. Profiled on one thread (six mug trials, 30 contacts): the nearest-face searches took 4.5 of 7.5 s before and 1.4 of 4.2 s after; the bound lookups 0.9 s in both; the cover\'s share rose to about a third (its KD-tree pair query for the neighbour lists, 2-10 ms a wide scale, is the largest part; a compiled brute-force scan, tried before, was slower again at these sizes: 4-14x). Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes mug,milk,can,lemon,bread,cereal --trials 6`, load average 0.3 before and 2.2 after; numba\'s default threads):\n\n| mesh | 5 contacts | 10 contacts | 30 contacts | median s at 30, before / after |\n|---|---|---|---|---|\n| mug | 1.32x | 1.15x | 1.30x | 0.723 / 0.575 |\n| milk | 1.22x | 1.06x | 1.16x | 0.457 / 0.377 |\n| can | 1.07x | 1.04x | 1.16x | 0.513 / 0.455 |\n| lemon | 0.99x | 1.10x | 1.05x | 0.851 / 0.807 |\n| bread | 1.10x | 0.97x | 1.23x | 0.421 / 0.351 |\n| cereal | 1.07x | 0.88x | 1.18x | 0.442 / 0.393 |\n\nEvery trial within 5 mm either way except on the cereal box: 4 / 6 against 5 / 6 at 5 contacts and 5 / 6 against 6 / 6 at 10. Rerun pose by pose, none of those is a search failure: each answer\'s log-likelihood is 0.3-2.2 nats above the truth\'s (seed 6002, 10 contacts: 10.7 mm off along a face the contacts do not pin, 2.2 nats above the truth). The 30-contact goal (0.2 s) is still 1.8-4x away; the cover at the wide scales (about 25 ms a scale at the cap) and the exact scales below two slacks (the last 17 of the mug\'s 42 with the posterior stage, about 150 ms on seed 5300) are what is left. `identify` (six objects, 10 contacts, 18 trials alternating with the commit before, load average 1.1 before and 2.1 after): 1.15x, median 2.13 s (longest 3.86 s) against 2.45 s (4.35 s), all 18 right with either. That day\'s run of the tables above (2026-11-29) was made after this step, the same evening, at a time when the second core gave little: on one thread the mug took what it had in the previous run of this benchmark (0.85 / 0.62 s at 5 / 10 contacts, against 0.84 / 0.72), on two threads longer than on one (0.97 / 0.80 s; the previous run 0.66 / 0.55 s, the tree before this step). So the absolute times and the ratios against f4e652e, whose cover is serial, came out lower than in that run (mug 1.02 / 0.71 / 0.63 s at 5 / 10 / 30 contacts against 0.64 / 0.56 / 0.50 s), while the same tree ran 1.21-1.27x faster than the commit before it, alternating trial by trial on the mug at 5 and 10 contacts and the milk carton at 5, in an A/B run right after the tables (`ab_speed.py HEAD~1 --contacts 5,10 --meshes mug,milk --trials 4`; the milk carton at 10 contacts 1.03x; the commit before took 1.18 s on the mug at 5 contacts there).'
        "\n\n" + 'Then the first scale\'s cover drawn from the region (docs/localization.md, "The first scale\'s cover"). The union of the 1,200-1,800 balls that survive the uniform start, each as wide as the region, holds the region or most of it, yet the rejection sampler counted each of its 24,000 draws (every one in nearly every ball) and kept 3-5 of them, in 22-46 ms (mug, 10 contacts, one thread): a tenth of a localisation. A grid test now finds the cells of the region that the balls hold whole, and where they are at least half of it the cover draws the region and keeps the draws that lie in the union: 6-9 ms, with the floor of 50 particles. Against the commit before (`ab_speed.py 37a9ad0 --contacts 5,10,30 --meshes mug,milk,can,lemon,bread,cereal --trials 6`, load average 0.2 before and 2.3 after; numba\'s default threads):\n\n| mesh | 5 contacts | 10 contacts | 30 contacts | median s at 10, before / after |\n|---|---|---|---|---|\n| mug | 0.99x | 1.16x | 1.22x | 0.795 / 0.661 |\n| milk | 1.18x | 1.06x | 1.26x | 0.531 / 0.488 |\n| can | 1.15x | 1.39x | 1.31x | 0.446 / 0.324 |\n| lemon | 1.17x | 1.07x | 1.03x | 0.532 / 0.472 |\n| bread | 1.23x | 1.30x | 1.26x | 0.416 / 0.317 |\n| cereal | 1.07x | 1.03x | 1.45x | 0.611 / 0.579 |\n\nEvery trial within 5 mm either way, except the milk carton at 5 contacts, 5 / 6 against 6 / 6 (seed 5504: 5.6 mm against 4.0 mm off, both answers 0.6 nats above the truth\'s log-likelihood, so not a search failure), and the cereal box as before. `identify` (six objects, 10 contacts, 18 trials alternating with the commit before, load average 2.3-2.4): 1.13x, median 1.76 s (longest 3.38 s) against 2.04 s (6.45 s), all 18 right with either. On one thread the gain is smaller in 6-DOF (CPU time 0.93-0.98x in the search study, section "The first scale\'s cover drawn from the region", which found no search failure in 648 development and held-out trials, against one with the rejection sampler): the old cover\'s full counts ran on the KD-tree\'s thread pool, whose waits the wall clock sees.'
        "\n\n" + 'Then the scales scored on the table two of Alg. 1\'s steps at a time (`bound_steps=2`, docs/localization.md, "Two of Alg. 1\'s steps at a time on the table"). After the step above, a per-scale trace of the mug at 10 contacts (seed 8001, one thread) put four tenths of the time in the ten scales at the particle cap (11-27 ms each, nearly all of it the cover: the scoring is a table lookup there), and cProfile of six trials half of all time in the covers (1.59 of 3.08 s; the KD-tree pair query for the neighbour lists a third of that). Those scales now take two of Alg. 1\'s steps at a time, so half as many covers: the mug\'s 10-contact localisation runs 29 scales instead of 42. Against the commit before (`ab_speed.py 1117c35 --contacts 5,10,30 --meshes mug,milk,can,lemon,bread,cereal --trials 6`; numba\'s default threads):\n\n| mesh | 5 contacts | 10 contacts | 30 contacts | median s at 5 / 10 / 30, before | after |\n|---|---|---|---|---|---|\n| mug | 1.43x | 1.55x | 1.60x | 0.98 / 0.71 / 0.53 | 0.67 / 0.46 / 0.25 |\n| milk | 1.53x | 1.42x | 1.37x | 0.82 / 0.41 / 0.35 | 0.55 / 0.30 / 0.25 |\n| can | 1.50x | 1.22x | 1.04x | 0.83 / 0.41 / 0.45 | 0.57 / 0.32 / 0.40 |\n| lemon | 1.19x | 1.13x | 1.02x | 1.00 / 0.54 / 0.81 | 0.84 / 0.49 / 0.75 |\n| bread | 1.57x | 1.83x | 1.29x | 0.74 / 0.29 / 0.23 | 0.46 / 0.15 / 0.18 |\n| cereal | 1.43x | 1.71x | 1.29x | 0.87 / 0.52 / 0.32 | 0.59 / 0.31 / 0.24 |\n\nThe same trials within 5 mm in every cell (the milk carton\'s seed 5504 and the cereal box\'s as before). `identify` (six objects, 10 contacts, 18 trials alternating with the commit before, load average 1.8-1.9): 1.30x, median 1.54 s (longest 2.75 s) against 2.12 s (5.63 s), all 18 right with either. The search study (section "Wide scales two steps at a time"): no search failure in 648 development and held-out trials either way; in 6-DOF the truth in the 90 % region in 254 of 288 trials against 265. With it the 10-contact goal (0.5 s) and the 5-contact one (1 s) hold on every bundled mesh in this run; at 30 contacts the bread takes 0.18 s, the cereal box, the mug and the milk carton 0.24-0.25 s, the can 0.40 s and the lemon, whose exact searches are the slowest per pair, 0.75 s (the goal is 0.2 s).'
        "\n\n" + 'Then BLAS on one thread inside the estimators and planners (`touchloc._util.blas_threads`, as the mapping package already did; `TOUCHLOC_BLAS_THREADS` sets another limit, 0 lifts it). Timing the mug at 5 contacts in one process per setting on an idle machine (six trials, medians) found two threads slower than one: 0.40 s with the process\'s defaults (numba and OpenBLAS on both cores), 0.30 s with numba on one thread, 0.19 s with OpenBLAS on one thread (`OPENBLAS_NUM_THREADS=1`) and numba on two. cProfile with numba and OpenBLAS both on one thread and both on two put the difference in the compiled kernels themselves: the cover\'s draws 0.06 against 0.25 s, its counts 0.11 against 0.28 s, the bound lookups 0.11 against 0.25 s, the pair query\'s plan 0.27 against 0.53 s. After each of the small products between them (the counting plan\'s probe, covariances), OpenBLAS\'s idle threads spin for a while before they sleep, on the same two cores as numba\'s. Against the commit before (`ab_speed.py f2b6c0e --contacts 5,10,30 --meshes mug,milk,can,lemon,bread,cereal --trials 6 --identify 12`, load average 0.7 before and 1.8 after; numba\'s default threads, BLAS\'s default in the process):\n\n| mesh | 5 contacts | 10 contacts | 30 contacts | median s at 5 / 10 / 30, before | after |\n|---|---|---|---|---|---|\n| mug | 1.75x | 1.44x | 1.02x | 0.40 / 0.27 / 0.15 | 0.24 / 0.20 / 0.15 |\n| milk | 1.51x | 1.37x | 1.06x | 0.30 / 0.18 / 0.10 | 0.20 / 0.13 / 0.10 |\n| can | 1.57x | 1.00x | 1.01x | 0.31 / 0.18 / 0.22 | 0.21 / 0.18 / 0.21 |\n| lemon | 2.07x | 1.02x | 0.99x | 0.56 / 0.22 / 0.36 | 0.26 / 0.21 / 0.37 |\n| bread | 1.64x | 0.95x | 1.01x | 0.28 / 0.08 / 0.12 | 0.17 / 0.09 / 0.12 |\n| cereal | 1.36x | 0.98x | 1.02x | 0.33 / 0.16 / 0.12 | 0.26 / 0.16 / 0.11 |\n\nThe same trials within 5 mm in every cell (the milk carton\'s seed 5504 and the cereal box\'s as before). `identify` (six objects, 10 contacts, 12 trials): 1.34x, median 0.55 s against 0.80 s, all 12 right with either. At 5 contacts the cover, with its small products between kernels, is most of the time; at 30 the likelihood is, and there nothing changed.'
        "\n\n" + 'Then the near lists\' reach on small meshes (docs/localization.md, "Measurement models"). A list exists for a (cell, normal bin) where some sample costs less than 25 d_M^2, a point within 5 sigma_pos (10 mm) of the surface, but only cells within three cells of the surface were sampled: 5.6 mm on the lemon, whose finest cells are 1.9 mm. Of the queries of poses 1 cm / 0.5 rad off (30 contacts) that cost less than 25, 73 % found a list on the lemon, 100 % on the mug, milk carton, can and bread. The cells within 5 sigma_pos plus half a cell diagonal of the surface are now sampled too (the lemon 5.6 to 11.6 mm, the bread 7.5 to 12.2, the can 10 to 12.9; the others unchanged): 100 % found on the lemon; its lists 13.6 to 20.2 MB, built once per mesh (and kept on disk) in 5.9-6.0 s instead of 3.8-4.2 s (cache off, two builds each alternating with the commit before; the bread 3.0-3.1 against 2.3-2.4 s, the can 2.8-3.0 against 2.6-2.7 s). A 14k-face bunny now keeps lists that its check dropped before: 781 to 556 ns a query (section "Likelihood grid: build time per mesh"). The fast method on the lemon, in one process each (best of three, two threads, 20,000 poses x 30 contacts): 7.6 to 9.9 M pairs/s close to the truth (2.7x to 3.6x exact), 1.8 to 2.2 M near it (1.5x to 1.9x). Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes lemon,can,bread --trials 6`, then `--contacts 10,30 --meshes bread,lemon --trials 10`): the lemon 1.05 / 1.14 / 1.17x at 5 / 10 / 30 contacts and 1.11 / 1.05x in the second run, the can 0.95 / 1.03 / 0.99x, the bread 0.97 / 0.95 / 0.97x and then 1.01 / 0.97x; every trial within 5 mm either way. Tried and not kept: the lists\' cost threshold raised from 25 to 50 d_M^2 (their winners below 100 instead of 50) took the fast method near the truth from 1.9x to 2.2x exact on the lemon and from 5.4x to 5.8x on the mug, at twice the memory (lemon 20 to 40 MB, mug 8 to 16 MB, can 8 to 17 MB).'
        "\n\n" + 'Then the lemon searched as a sphere at its wide scales (docs/localization.md, "Near-spheres"). A per-scale trace at 30 contacts (seeds 0 and 1, two threads) put 170 of 270-290 ms in the ten scales that filled the particle cap (delta 12.4 to 4.4 mm, 15-18 ms each, three quarters of it the likelihood) and 50-70 ms in the last scale with the posterior stage: at those scales the belief spans most rotations (standard deviations of 60-90 deg about every axis), the lemon being 2.5 mm off a sphere. It is now searched by the position of its centre alone down to twice that, or to 0.18 rho where that is wider (where one centre\'s rotations hold a particle a ball within the cap), and the first narrower scale covers every rotation around the centres found: two scales at the cap remain. Against the commit before (`ab_speed.py HEAD~1 --contacts 5,10,30 --meshes lemon,mug,can --trials 8`, load average 1.4-1.6): the lemon 3.32x / 2.82x / 2.47x at 5 / 10 / 30 contacts (medians 0.056 / 0.062 / 0.123 s against 0.186 / 0.171 / 0.303 s), the mug and the can, which are not near-spheres, 1.00-1.04x; every trial within 5 mm either way. That first version capped the cover at the switch at the particle cap, about a particle a ball of the lemon\'s rotations, and at 60 contacts missed the true turn in 2 of 10 trials; the switch\'s cover now holds m a ball (up to m times the cap), which costs most of the saving: against 577b6d2, the tree before both (`ab_speed.py 577b6d2 --contacts 5,10,30 --meshes lemon --trials 8`), the lemon 2.11x / 1.81x / 1.50x (medians 0.094 / 0.113 / 0.228 s against 0.202 / 0.208 / 0.347 s), every trial within 5 mm either way. The search study on the lemon and five held-out near-spheres is in section "Near-spheres searched as spheres at the wide scales".'
        "\n\n" + 'Then the near lists packed one 64-bit entry a list (docs/localization.md, "Measurement models"). In real localisations at 30 contacts nearly every pair evaluated is answered by a near list (99.2 % on the lemon, 97.0 % on the mug, 96.1 % on the bread; 4 trials each, the pairs each call evaluates), so the near list\'s path is the likelihood\'s time. A near query\'s own arithmetic is small against its waits on memory: one thread, 20,000 near-truth queries on the lemon took 344 ns each in the order the poses give them, 143 ns sorted by cell and 65 ns when all were the same query (bread 110 / 57 / 33, mug 105 / 73 / -, milk carton 57 / 46 / 30). Each query read three arrays in turn: its cell\'s record, the list\'s offset, then the list\'s faces (the lemon\'s lists 22 MB). Each list now sits in one 64-bit entry (face ids of 8-10 bits on the bundled meshes, up to 6-8 a list; 93.6-100 % of the lists fit, the rest are stored apart behind their entry), so a query reads its record and its entry. Lists: lemon 22.0 to 11.9 MB, mug 8.2 to 4.7, can 8.5 to 5.2, bread 8.7 to 6.3, milk carton 1.3 to 1.0, cereal box 1.4 to 1.0. Every answer is bit for bit the same (the budgeted costs of 3000 poses at 2 mm, 1 cm and 5 cm from the truth on all six meshes). The list path alone, one thread, 4,000 poses x 30 contacts: lemon 217 to 184 ns at 2 mm and 311 to 224 at 1 cm, bread 115 to 61 and 183 to 115, mug 95 to 78 and 134 to 106, milk carton 51 to 39 and 69 to 54, can 179 to 146 and 231 to 131. Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes mug,milk,can,lemon,bread,cereal --trials 8`, load average 1.1-1.7):\n\n| mesh | 5 contacts | 10 | 30 | 30 contacts, before / after (median s) |\n|---|---|---|---|---|\n| mug | 1.09x | 1.10x | 1.11x | 0.111 / 0.112 |\n| milk carton | 0.97x | 1.01x | 1.03x | 0.084 / 0.081 |\n| can | 1.06x | 1.14x | 1.19x | 0.161 / 0.134 |\n| lemon | 0.99x | 1.09x | 1.20x | 0.172 / 0.145 |\n| bread | 1.11x | 1.12x | 1.08x | 0.080 / 0.078 |\n| cereal box | 1.06x | 1.11x | 0.99x | 0.098 / 0.089 |\n\nThe same trials within 5 mm either way (140 of 144). Tried and not kept: touching the next queries\' cell records (and then their entries) two to eight queries ahead, so that their waits overlap: 0.8-1.0x on the list path of every mesh; the processor already overlaps what it can. The bound table\'s one-thread kernel (the pruning\'s lookups for batches under 4,096 pairs) now goes through numba\'s parallel pipeline over a plain loop, as the likelihood\'s one-thread kernels already did: 25-33 ns a lookup instead of 55-68 (one thread, 3000 poses x 30 contacts near the truth, mug and lemon; the same bounds bit for bit). Compiled so, the cover\'s one-thread kernels were 0.5-1.2x their plain selves, so they stay as they are. Not tried: sorting a batch\'s queries by cell, which gave the 2x above on a fixed set, but which the budgeted pass cannot do as it stands (each pose takes its contacts in order until its budget is spent).'
        "\n\n" + "Then where the second thread does not help (cProfile of six mug localisations at 5 contacts, numba on one thread and on two, this tree): 224 against 173 ms a localisation. The likelihood (63 to 31 ms), the bound lookups (17 to 9), the cover's counts (17 to 10) and draws (9 to 5) halve; the cover's neighbour lists do not: scipy's `cKDTree.query_pairs` within two radii of 1,000-1,900 centres in the 7-D embedding, about 11,000 pairs and 1.4 ms a call, 28 calls, 38-44 ms a localisation on either thread count, a quarter of the time on two threads and the largest part that caps more cores. Tried and not kept: the pairs from a compiled sweep along the widest coordinate on two threads (the same pairs, 3.1x slower: a slab of that coordinate holds most centres), `query_ball_point(..., workers=2)` with the lists joined in numpy (4.1x slower), and other tree settings (leaf size 8-64, unbalanced, uncompact nodes: 0.88-1.34x the time of build and query together)."
        "\n\n" + "Then the box-like meshes at 30 contacts, measured again with more trials (`ab_speed.py f4e652e --contacts 30 --meshes bread,milk,cereal --trials 12`, 2026-11-30): bread 2.23x, milk carton 2.61x, cereal box 2.22x (f4e652e 0.153 / 0.224 / 0.211 s, this tree 0.066 / 0.076 / 0.093 s; 12 of 12 within 5 mm on both). The rows above, at 2-3 trials, put them at 2.6-3.3x: on these meshes the 3x goal is not met. cProfile of eight localisations each: the cover 25-34 ms, the scales' likelihood and bound lookups 24-34 ms (the lookups 11-16 ms of it), the posterior stage 16-18 ms (5-6 tempering stages, 15-19 moves of 500 particles, acceptance 0.62). Tried and not kept: the pruned scales without the bound table (32 random particles bound the best cost, every particle stops on its budget alone): 0.88-1.00x at 30 contacts on the bread, cereal box, milk carton and mug, 1.01x on the lemon, 0.99-1.04x at 5 contacts; and compiled two-thread pair queries for the cover, timed on 228 recorded calls (mug, lemon and bread at 5 contacts; each gave scipy's lists on the four calls compared): scipy's tree 1.05 ms a call, a sweep along the widest coordinate 1.39, a grid over the two / three / four widest coordinates 1.73 / 1.60 / 2.33, leaves of 8 / 16 / 32 centres in KD order tested box by box 4.77 / 2.99 / 1.95, every pair 2.84. And the likelihood's budgeted pass run contact by contact over blocks of 8-128 poses (each pose's pairs in their own order, so the same costs bit for bit), so that a block's queries of one contact fall in nearby cells: 0.87-1.03x on the calls of three localisations each of the lemon and the mug at 5 and 30 contacts, and 0.65-0.88x with the poses first sorted by the cell of their first contact. The calls themselves did not wait on memory the way the near-truth queries above did: the lemon's 0.99 M pairs a localisation at 30 contacts took 58 ns each."
        "\n\n" + "Like for like on those meshes, with the posterior stage off so that this tree ends where f4e652e ends (`ab_speed.py f4e652e --contacts 30 --meshes bread,milk,cereal --trials 12 --options '{\"final_moves\": 0}'`, 2026-11-30, two runs, each next to a run with the defaults): bread 3.37 / 2.98x, milk carton 3.32 / 3.07x, cereal box 3.10 / 3.06x (this tree 0.049-0.067 s), against 2.24 / 2.39 / 2.17x with the posterior stage in the run between them; 12 of 12 within 5 mm in every row. Alg. 1 itself is about 3x faster at 30 contacts there; the posterior stage costs 20-25 ms of the 0.07-0.09 s."
        "\n\n" + "Then the table's lookups stop once a particle is sure to be pruned (the scales scored on the table alone). cProfile of eight bread localisations at 30 contacts (one thread, 0.11 s each): the likelihood's compiled pass 30 %, the covers 27 %, the posterior stage 28 % (its moves' likelihood 19 of 31 ms), and the bound lookups 19 % (21 ms a localisation; 12 of their 26 calls, the largest, at the scales scored on the table alone). Those scales looked up every pair, while their prune keeps 18-23 % of the particles. The best bound sum of 32 particles spread over the batch now sets the prune's limit, and each particle's lookups, taken in the order of those 32's largest bounds, stop once their sum reaches it: 63 % of the pairs are looked up (bread, 30 contacts, four localisations). The prune keeps the same particles with the same values (tested); a hash of 27 localisations (bread, mug and lemon at 5, 10 and 30 contacts) is unchanged. Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes bread,cereal,milk,mug,lemon,can --trials 8`, load average 0.9-1.4): 0.98-1.06x, median 1.03x; at 30 contacts bread 1.05x, cereal box 1.01x, milk carton 1.03x, mug 1.04x, lemon 1.00x, can 1.05x; the same trials within 5 mm either way. A small step: the 3x goal at 30 contacts with the posterior stage needs about 1.3x more on the box-like meshes, and no single part of the profile holds it."
        "\n\n" + "The tail, measured apart with more trials (this tree only, 20 trials per cell, seeds 9000 + 100 k + s, two threads, load average 1.6-1.8, 2026-11-30; mug, milk carton, can, lemon, bread and cereal box at 5, 10 and 30 contacts): p95 / median 1.06-1.37 in every cell (the goal: at most 3), and the longest of the 360 localisations 0.20 s. Medians 0.08-0.17 s at 5 contacts, 0.08-0.15 s at 10 and 0.07-0.16 s at 30. Within 5 mm: 19-20 of 20 in every cell but the cereal box at 5 contacts (13 of 20). Each of the ten answers off by more (5.4-10 mm; cereal box 7, mug, milk carton and bread one each) has a log-likelihood at least that of the truth (0.7-5.8 nats above it, one 0.05 below): five contacts leave a box's faces free to slide, so these are not search failures."
        "\n\n" + "Then the bounds skipped at the exact scales narrower than the table's slack. Traced per scale (bread, 30 contacts, three localisations), the share of particles the bounds stopped without a search fell from 40-74 % at 1.7-1.9 slacks to 0-15 % below one slack, where the median bound was 0-9 % of its cost: there the table's dilation covers the particles' whole spread. Those scales now bound the best cost with 32 particles spread over the batch and stop each particle on its costs alone; the kept particles and their values are the same (tested at both kinds of scale; the hash of the 27 localisations above unchanged). One thread, CPU time, alternating in one process (10 trials per cell, 10 and 30 contacts): 0.96-1.07x, median 1.02x, over the six meshes with the bounds skipped below 0.7 slack, and 0.99-1.10x over the bread, cereal box, mug and lemon below one slack (the rule kept); against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes bread,cereal,milk,mug,lemon,can --trials 8`, load average 1.7-1.9): 0.98-1.07x, median 1.02x, the same trials within 5 mm."
        "\n\n" + "Then the near lists in one plane (docs/localization.md, \"Measurement models\"). The queries that real localisations evaluate at 30 contacts (four each; the pairs up to where each row stops) are 93-96 % near-listed on the bread, milk carton and mug, and a near-listed query's time (one thread, 62-116 ns in its own order) went to the list's faces more than to finding the list: bread 20 ns for the cell's record and entry against 38 ns for its 2.0 faces (0.5 closest points), milk carton 12 / 29 ns. 74-95 % of those queries on the bread, milk carton and cereal box, 40 % on the mug, find a list whose faces all lie in one plane, where the face that holds the query's projection is the answer. Such lists are now marked: a query tests the faces' edges until one holds its projection and returns its plane cost, and a list whose whole cell projects into one of its faces keeps that face alone (one plane distance). Answers bit for bit the same (220,000 queries a mesh, six meshes). Near-listed queries, one thread: bread 87-92 to 77-82 ns, milk carton 61-64 to 51, cereal box 60-65 to 50, mug level (1 % of its queries land on single-face plane lists, 26 % on coplanar ones). The lists' calls replayed (fast / exact, two runs each): bread 3.2 / 3.2x to 3.2 / 3.5x at 10 contacts and 3.1 / 3.6x to 3.4 / 3.0x at 30, cereal box 3.3 / 3.2x to 3.5 / 3.6x and 4.1 / 4.2x to 4.2 / 4.2x, milk carton 3.4 / 3.3x to 3.5 / 3.5x and 3.7 / 3.4x to 3.7 / 3.7x: within the runs' spread. Against the commit before (`ab_speed.py HEAD --contacts 5,10,30 --meshes bread,cereal,milk,mug,can --trials 8`, load average 1.4-1.5): 0.99-1.10x, median 1.03x (cereal box 1.10x and bread 1.07x at 30 contacts), the same trials within 5 mm. What is left on those meshes is the lists of two or more planes, along the edges: 25-43 % of the near-listed queries at 64-101 ns, against 26-31 ns on a plane list and 45-64 on a coplanar one. Measured since and not kept: (1) the cover's counter (the centres' KD-tree and pair lists, a third of a 5-contact localisation on the mug) built on a second Python thread while the first batch is drawn. `query_pairs` releases the GIL and the results were bit for bit the same, but on 2 cores the draws ran 1.6-3x slower beside it (19 to 48-58 ms a localisation, numba's OpenMP threads sharing the cores): 0.92-1.03x whole localisations. (2) A near list's closest points taken best first (all bounds, then the lowest): the same answers, 219 to 193-200 ns a near-listed query on the lemon and 97 to 91 on the mug, but 1-3 ns slower on the bread, milk carton and cereal box, whose plain lists hold about two faces.")
HELD_OUT = ["can", "lemon", "bread", "cereal"]
#: a near-spherical mesh of the size of a football (issue's "any mesh up to 10k faces, near-spherical
#: ones included"): a 110 mm sphere of 5120 faces with bumps of +-0.7 mm, so that no rotation is an
#: exact symmetry; written to a file both workers load
BALL = "ball"


def _ball_mesh(path: Path) -> str:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=0.11)
    u = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    polar, azim = np.arccos(np.clip(u[:, 2], -1, 1)), np.arctan2(u[:, 1], u[:, 0])
    m.vertices = u * (0.11 * (1.0 + 0.006 * np.cos(5 * polar) * np.cos(3 * azim)))[:, None]
    m.export(path)
    return str(path)


# -- worker side -------------------------------------------------------------------------
def _trial(obj, region, k, seed):
    from bench_localization import trial  # the localisation benchmark's trials (2 mm / 5 deg)

    return trial(obj, region, k, seed)


def worker() -> int:
    warnings.simplefilter("ignore")
    from touchloc.belief import PoseRegion, ScalingSeries, add_s, identify
    from touchloc.data import load_object
    from touchloc.models import ProximityModel

    cube = PoseRegion.box((0, 0, 0), 0.2, "full")
    models = {}

    def model(name):
        if name not in models:
            if name.endswith(".obj"):
                from touchloc.models import MeshObject

                obj = MeshObject.from_file(name)
            else:
                obj = load_object(name)
            models[name] = ProximityModel(obj, 0.002, np.deg2rad(5))
            _, c = _trial(models[name].obj, cube, 30, 0)  # compile kernels, build grids
            ScalingSeries(models[name], rng=0, progress=False).localize(c, cube)
        return models[name]

    import touchloc

    print(json.dumps({"ready": True, "touchloc": touchloc.__file__}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        if req.get("kind") == "identify":
            ms = {n: model(n) for n in req["meshes"]}
            region = PoseRegion.box((0, 0, 0), 0.1, "full")
            true, c = _trial(ms[req["truth"]].obj, region, req["k"], req["seed"])
            t0 = time.perf_counter()
            post = identify(ms, c, region, rng=req["seed"])
            dt = time.perf_counter() - t0
            print(json.dumps({"time": dt, "correct": max(post, key=post.get) == req["truth"]}), flush=True)
            continue
        if req.get("kind") == "likelihood":
            print(json.dumps(_likelihood(model(req["mesh"]), cube, req["k"], req["seed"])), flush=True)
            continue
        if req.get("kind") == "replay":
            print(json.dumps(_replay(model(req["mesh"]), cube, req["k"], req["seeds"])), flush=True)
            continue
        if req.get("kind") == "cover":
            print(json.dumps(_cover(model(req["mesh"]), cube, req["k"], req["seed"])), flush=True)
            continue
        m = model(req["mesh"])
        true, c = _trial(m.obj, cube, req["k"], req["seed"])
        t0 = time.perf_counter()
        b = ScalingSeries(m, rng=req["seed"], progress=False, **req.get("options", {})).localize(c, cube)
        dt = time.perf_counter() - t0
        print(json.dumps({"time": dt, "adds": float(add_s(m.obj, b.map_pose(), true)),
                          "evaluations": int(b.info.get("evaluations", 0))}), flush=True)
    return 0


def _likelihood(m, cube, k, seed):
    """Pose-contact pairs per second of the exact and fast likelihoods, on poses near the
    truth (a late scale) and poses anywhere in the region (an early scale)."""
    rng = np.random.default_rng(seed)
    true, c = _trial(m.obj, cube, k, seed)
    region = cube.with_rho(m.obj.radius)
    near = region.perturb(np.repeat(true[None], 20000, axis=0), 0.01, rng=rng, ball=False)
    far = region.sample(4000, rng=rng)
    close = region.perturb(np.repeat(true[None], 20000, axis=0), 0.002, rng=rng, ball=False)
    out = {}
    for label, X in (("near", near), ("far", far), ("close", close)):
        costs = {}
        for method in ("exact", "fast"):
            m.contact_costs(X[:100], c, method=method)
            t0 = time.perf_counter()
            costs[method] = m.contact_costs(X, c, method=method)
            out[f"{label}_{method}"] = X.shape[0] * len(c) / (time.perf_counter() - t0)
        err = (costs["fast"] - costs["exact"]).ravel()
        out[f"{label}_err"] = [float(np.percentile(err, 99)), float(err.max()), float(err.min())]
    return out


def record_calls(m, cube, k, seeds):
    """The likelihood calls of one localisation per seed, as (poses, contacts, budget,
    lower): what the estimator asks the model for (also ``study_fast_anatomy.py``'s input)."""
    from touchloc.belief import ScalingSeries

    calls = []
    costs = m._budget_costs

    def recorded(X, contacts, method=None, budget=None, lower=None):
        calls.append((X.copy(), contacts, budget, lower))
        return costs(X, contacts, method, budget, lower)

    m._budget_costs = recorded
    try:
        for seed in seeds:
            _, c = _trial(m.obj, cube, k, seed)
            ScalingSeries(m, rng=seed, progress=False).localize(c, cube)
    finally:
        del m._budget_costs
    return calls


def _replay(m, cube, k, seeds):
    """The likelihood calls of whole localisations (one per seed), replayed with the fast
    and the exact method: seconds per localisation each (the faster of two passes), and the
    pairs per call. These are the pairs the estimator asks for, with their budgets and
    bounds (the budgeted pass stops a pose's row at the prune threshold)."""
    calls = record_calls(m, cube, k, seeds)
    costs = m._budget_costs
    out = {}
    for method in ("fast", "exact", "fast", "exact"):
        t0 = time.perf_counter()
        for X, c, budget, lower in calls:
            costs(X, c, method, budget, lower)
        dt = (time.perf_counter() - t0) / len(seeds)
        out[method] = min(out.get(method, np.inf), dt)
    out["calls"] = len(calls) / len(seeds)
    return out


def _cover(m, cube, k, seed):
    """Seconds spent in the cover step of one localisation, and the same cover step of the
    reference implementation on the same centres (current tree only)."""
    from touchloc.belief import ScalingSeries

    true, c = _trial(m.obj, cube, k, seed)
    ss = ScalingSeries(m, rng=seed, progress=False)
    if not hasattr(ss, "_even_density_cover_reference"):
        return {}
    fast, ref = ss._even_density_cover, ss._even_density_cover_reference
    spent = {"cover": 0.0, "reference": 0.0}

    def timed(region, centers, dp, d, *sym):
        t0 = time.perf_counter()
        ref(region, centers, dp, d)
        t1 = time.perf_counter()
        out = fast(region, centers, dp, d, *sym)
        spent["reference"] += t1 - t0
        spent["cover"] += time.perf_counter() - t1
        return out

    pairs = [0]
    name = "_budget_costs" if hasattr(m, "_budget_costs") else "_contact_costs"
    costs = getattr(m, name)

    def counted(X, contacts, *args, **kw):
        out = costs(X, contacts, *args, **kw)
        if name == "_contact_costs":
            pairs[0] += len(X) * len(contacts)
            return out
        cost, done = out
        # a row stopped by its budget: the pairs up to its last non-zero one were evaluated
        stopped = cost[~done] != 0
        last = stopped.shape[1] - np.argmax(stopped[:, ::-1], axis=1)
        pairs[0] += int(done.sum()) * len(contacts) + int(np.where(stopped.any(axis=1), last, 1).sum())
        return out

    ss._even_density_cover = timed
    setattr(m, name, counted)
    try:
        b = ss.localize(c, cube)
    finally:
        delattr(m, name)
    spent["pairs_fraction"] = pairs[0] / (b.info["evaluations"] * len(c))
    return spent


# -- driver side -------------------------------------------------------------------------
def _Worker(path: Path, threads: int | None):
    """A worker on the touchloc of ``path``, with ``threads`` numba threads (None: numba's default)."""
    from _common import TreeWorker

    return TreeWorker(__file__, path, {"NUMBA_NUM_THREADS": str(threads)} if threads else None)


def _fmt_row(label, k, base, cur):
    tb = np.array([r["time"] for r in base]) if base else None
    tc = np.array([r["time"] for r in cur])
    sc = np.mean([r["adds"] < 0.005 for r in cur])
    row = [label, k, len(tc), f"{np.median(tc):.2f}", f"{np.percentile(tc, 95) / np.median(tc):.1f}",
           f"{100 * sc:.0f} %"]
    if base:
        sb = np.mean([r["adds"] < 0.005 for r in base])
        row += [f"{np.median(tb):.2f}", f"{100 * sb:.0f} %", f"{np.median(tb / tc):.1f}x",
                f"{np.median([r['evaluations'] for r in base]) / np.median([r['evaluations'] for r in cur]):.2f}"]
    return row


def run(quick: bool = False) -> str:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import baseline_tree, table

    threads = int(os.environ.get("TOUCHLOC_BENCH_THREADS", "0")) or None
    # (mesh, contacts, trials): few trials at 5 contacts, where the baseline takes longest
    if quick:
        cases = [("mug", 5, 1), ("mug", 10, 1), ("mug", 30, 1), ("can", 10, 1)]
    else:
        cases = [(m, k, 2 if k == 5 else 3) for m in TUNED for k in (5, 10, 30)]
        cases += [(m, 10, 2) for m in HELD_OUT[:2]] + [(m, 30, 2) for m in HELD_OUT[2:]]
        cases += [(BALL, 10, 2), (BALL, 30, 2)]
    with tempfile.TemporaryDirectory() as tmpd:
        ball = _ball_mesh(Path(tmpd) / "ball.obj")
        base_path = baseline_tree(BASELINE, Path(tmpd) / "base")
        cur = _Worker(ROOT, threads)
        base = _Worker(base_path, threads) if base_path else None
        rows, load = [], [os.getloadavg()[0]]
        # the posterior stage after the last scale (absent at the baseline) as an option
        import inspect

        from touchloc.belief import ScalingSeries

        stage_option = "final_moves" in inspect.signature(ScalingSeries).parameters
        try:
            for mesh, k, seeds in cases:
                rb, rc, ro = [], [], []
                for s in range(seeds):
                    seed = 5000 + 100 * k + s
                    name = ball if mesh == BALL else mesh
                    if base:
                        rb.append(base.ask(mesh=name, k=k, seed=seed))
                    rc.append(cur.ask(mesh=name, k=k, seed=seed))
                    if stage_option:
                        ro.append(cur.ask(mesh=name, k=k, seed=seed, options={"final_moves": 0}))
                label = mesh + ("" if mesh in TUNED else " (held out)")
                if mesh == BALL:
                    label = "ball (held out: near-spherical, 5120 faces)"
                row = _fmt_row(label, k, rb, rc)
                if stage_option:
                    t_off = np.array([r["time"] for r in ro])
                    row += [f"{np.median(t_off):.2f}", f"{100 * np.mean([r['adds'] < 0.005 for r in ro]):.0f} %"]
                    if rb:
                        row.append(f"{np.median(np.array([r['time'] for r in rb]) / t_off):.1f}x")
                rows.append(row)
            # threads: the same trials on one thread
            thread_rows = []
            n_thr = threads or os.cpu_count() or 1
            if n_thr > 1:
                one = _Worker(ROOT, 1)
                try:
                    for mesh, k in (("mug", 5), ("mug", 10), ("can", 30)) if not quick else (("mug", 10),):
                        t1, tn = [], []
                        for s in range(3 if not quick else 1):
                            seed = 5000 + 100 * k + s
                            t1.append(one.ask(mesh=mesh, k=k, seed=seed)["time"])
                            tn.append(cur.ask(mesh=mesh, k=k, seed=seed)["time"])
                        speed = float(np.median(np.array(t1) / np.array(tn)))
                        # Amdahl: the share p of one thread's time that ran in parallel, from the
                        # speed-up on n threads, and what that share would give on 8
                        p = float(np.clip((1 - 1 / speed) / (1 - 1 / n_thr), 0.0, 1.0))
                        thread_rows.append([mesh, k, f"{np.median(t1):.2f}", f"{np.median(tn):.2f}", f"{speed:.2f}x",
                                            f"{100 * speed / n_thr:.0f} %", f"{100 * p:.0f} %",
                                            f"{1 / ((1 - p) + p / 8):.1f}x"])
                finally:
                    one.close()
            # identify among six objects from 10 contacts
            id_rows = []
            six = ["bread", "can", "cereal", "lemon", "milk", "mug"]
            for s, truth in enumerate(six[:1] if quick else six):
                rb = base.ask(kind="identify", meshes=six, truth=truth, k=10, seed=300 + s) if base else None
                rc = cur.ask(kind="identify", meshes=six, truth=truth, k=10, seed=300 + s)
                id_rows.append([truth, f"{rc['time']:.2f}", "yes" if rc["correct"] else "no"]
                               + ([f"{rb['time']:.2f}", "yes" if rb["correct"] else "no",
                                   f"{rb['time'] / rc['time']:.1f}x"] if rb else []))
            # components: the cover step alone, and the likelihood alone
            cov = [cur.ask(kind="cover", mesh=mesh, k=k, seed=7000 + k)
                   for mesh, k in (("mug", 5), ("milk", 10))]
            lik_rows = []
            # the lemon: a smooth mesh, whose cells list many faces
            for mesh, k in ((("mug", 5), ("mug", 30), ("lemon", 30), ("milk", 30), ("can", 30)) if not quick
                            else (("mug", 5),)):
                lc = cur.ask(kind="likelihood", mesh=mesh, k=k, seed=9000 + k)
                lb = base.ask(kind="likelihood", mesh=mesh, k=k, seed=9000 + k) if base else None
                for where in ("close", "near", "far"):
                    if where + "_exact" not in lc:
                        continue
                    r = [mesh, k, where, f"{lc[where + '_exact'] / 1e6:.2f}", f"{lc[where + '_fast'] / 1e6:.2f}",
                         f"{lc[where + '_fast'] / lc[where + '_exact']:.1f}x",
                         " / ".join(f"{v:.2g}" for v in lc[where + "_err"])]
                    if lb and where + "_exact" in lb:
                        r += [f"{lc[where + '_exact'] / lb[where + '_exact']:.1f}x",
                              f"{lc[where + '_fast'] / lb[where + '_fast']:.1f}x"]
                    elif lb:
                        r += ["", ""]
                    lik_rows.append(r)
            # the likelihood on the calls whole localisations make (current tree only)
            replay_rows = []
            for mesh in (TUNED + HELD_OUT if not quick else ["mug"]):
                for k in ((5, 10, 30) if not quick else (10,)):
                    r = cur.ask(kind="replay", mesh=mesh, k=k, seeds=[5000 + 100 * k + s for s in range(4)])
                    replay_rows.append([mesh, k, f"{r['calls']:.0f}", f"{1e3 * r['exact']:.1f}", f"{1e3 * r['fast']:.1f}",
                                        f"{r['exact'] / r['fast']:.1f}x"])
        finally:
            cur.close()
            if base:
                base.close()
        load.append(os.getloadavg()[0])
    head = ["mesh", "contacts", "trials", "median s", "p95 / median", "ADD-S < 5 mm"]
    if base_path:
        head += [f"baseline {BASELINE} median s", "baseline ADD-S < 5 mm", "speed-up (median of per-trial ratios)",
                 "likelihood evaluations, baseline / current"]
    if stage_option:
        head += ["posterior stage off (`final_moves=0`, Alg. 1 as the baseline ends): median s", "ADD-S < 5 mm"]
        if base_path:
            head.append("speed-up")
    text = [
        "Hidden pose uniform in a 400 mm cube with uniform rotation; k contacts sampled over the "
        "surface with 2 mm / 5 deg noise; `ScalingSeries(ProximityModel(obj, 0.002, np.deg2rad(5)), "
        "rng=seed).localize` with default settings. Each trial runs in two worker processes, this "
        f"checkout and commit {BASELINE} (`git archive`), one after the other, so both see the same "
        f"load; kernels compiled and grids built before timing. Threads: "
        f"{threads or os.cpu_count()}. Load average (1 min) before / after: "
        f"{load[0]:.1f} / {load[-1]:.1f} on {os.cpu_count()} cores.",
        table(head, rows),
        STATUS,
        NOTE,
        "The cover step alone (`_even_density_cover` against `_even_density_cover_reference`, the "
        "implementation of the baseline, both run on the same centres at every scale of one "
        "localisation), and the share of pose-contact pairs the likelihood still evaluates now "
        "that intermediate scales stop at the prune threshold (1.00 before):",
        table(["mesh", "contacts", "reference s", "current s", "speed-up",
               "pose-contact pairs evaluated / (particles x contacts)"],
              [[mesh, k, f"{r['reference']:.2f}", f"{r['cover']:.2f}", f"{r['reference'] / r['cover']:.1f}x",
                f"{r['pairs_fraction']:.2f}"]
               for (mesh, k), r in zip((("mug", 5), ("milk", 10)), cov) if r]),
        "The likelihood alone (`contact_costs`, M pose-contact pairs per second): 20000 poses "
        "within about 2 mm / 0.02 rad of the truth ('close', as in a posterior sample and its moves), "
        "20000 within about 1 cm / 0.1 rad ('near', as at late scales) and 4000 poses "
        "anywhere in the cube ('far', as at the first scales). 'fast - exact' is the error of the "
        "fast method in d_M^2 (99th percentile / max / min over all pairs; never negative by "
        "construction).",
        table(["mesh", "contacts", "poses", "exact M/s", "fast M/s", "fast / exact", "fast - exact (p99 / max / min)"]
              + (["exact vs baseline", "fast vs baseline"] if base_path else []), lik_rows),
    ]
    text += ["The same likelihood on the calls that whole localisations make (four seeds per row, the "
             "speed benchmark's trials): every call of `ScalingSeries.localize` recorded with its poses, "
             "budgets and bounds, then replayed with each method (the faster of two passes; milliseconds "
             "per localisation). These are the pairs the estimator asks for: most near the surface, and "
             "a pose's row stops at the prune threshold.",
             table(["mesh", "contacts", "calls per localisation", "exact ms", "fast ms", "fast / exact"],
                   replay_rows)]
    text += ["`identify` among six objects (bread, can, cereal, lemon, milk, mug) from 10 contacts "
             "(2 mm / 5 deg), pose uniform in a 200 mm cube, default settings; one trial per row:",
             table(["true object", "current s", "correct"] + ([f"baseline {BASELINE} s", "correct", "speed-up"]
                                                              if base_path else []), id_rows),
             f"Median over the {len(id_rows)} trials: {np.median([float(r[1]) for r in id_rows]):.2f} s "
             f"(longest {max(float(r[1]) for r in id_rows):.2f} s)."]
    if thread_rows:
        n_thr = threads or os.cpu_count()
        text += [f"Threads: the same localisations (three seeds per row, medians) on 1 thread and on {n_thr} "
                 "(numba threads of the likelihood and cover kernels; `NUMBA_NUM_THREADS` per worker process). "
                 "Efficiency is the speed-up divided by the thread count; on a shared machine the other "
                 "processes take part of the second core. 'Parallel share' is Amdahl's p, the share of the "
                 f"one-thread time that ran in parallel, solved from the speed-up on {n_thr} threads "
                 "(S = 1 / (1 - p + p / n)); '8 threads, projected' is what that share allows on 8 "
                 "(1 / (1 - p + p / 8)), a ceiling that assumes perfect scaling of the parallel part: "
                 "this machine cannot measure 8 threads.",
                 table(["mesh", "contacts", "1 thread s", f"{n_thr} threads s", "speed-up",
                        "efficiency", "parallel share", "8 threads, projected"], thread_rows)]
    return "\n\n".join(text)


if __name__ == "__main__":
    if "--worker" in sys.argv:
        sys.exit(worker())
    print(run(quick="--quick" in sys.argv))
