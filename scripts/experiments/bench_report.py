"""meso bench's report: the figures (error-vs-time curves, image grids with error insets,
the zoom-out sequence) and report.md (Tables 3 and 4, the bias/variance split). Split out of
scripts/experiments/bench, which calls figures() and report() once its rows are measured."""
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

LABELS = {"reference": "reference", "original": "original (full-res geometry)", "forig_hlow": "f_orig on h_low",
          "flow": "f'_low", "leadr": "LEADR", "vmf": "vMF", "ours": "ours: LoD chain, f'_low·R (R_ir under GI)",
          "ours_fixed": "ours at the fixed level", "ours_single": "ours LoD chain, f'_low·R",
          "ours_ir": "ours LoD chain, f'_low·R_ir", "ours_fixed_single": "ours fixed level, f'_low·R",
          "ours_fixed_ir": "ours fixed level, f'_low·R_ir"}
COLORS = {"original": "C0", "forig_hlow": "C1", "flow": "C2", "leadr": "C3", "vmf": "C4", "ours": "C5",
          "ours_fixed": "C6", "ours_single": "C7", "ours_ir": "C8", "ours_fixed_single": "C9", "ours_fixed_ir": "k"}
SHORT = {"original": "original", "forig_hlow": "f_orig/h_low", "flow": "f'_low", "leadr": "LEADR", "vmf": "vMF",
         "ours": "ours (LoD)", "ours_fixed": "ours fixed", "ours_single": "ours LoD R", "ours_ir": "ours LoD R_ir",
         "ours_fixed_single": "ours fixed R", "ours_fixed_ir": "ours fixed R_ir"}
def log(msg):
    print(msg, file=sys.stderr, flush=True)


def fmt_s(s):
    return f"{s / 60:.1f} min" if s >= 120 else f"{s:.0f} s"



# ----------------------------------------------------------------------------- report

def tonemap(x, scale):
    return np.clip((x * scale) / (1 + x * scale), 0, 1) ** (1 / 2.2)


def figures(a, rows, images, frames):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("meso bench: matplotlib missing (apt install python3-matplotlib): no PNG figures")
        return []
    made = []
    # Error against time, log-log.
    n = len(rows)
    cols = min(n, 3)
    nr = (n + cols - 1) // cols
    fig, axs = plt.subplots(nr, cols, figsize=(4.2 * cols, 3.3 * nr), squeeze=False)
    for ax, r in zip(axs.flat, rows):
        for m, runs in r["methods"].items():
            t = [x["time_s"] for x in runs]
            e = [x["mse"] for x in runs]
            lw = 2.2 if m in ("original", r["ours"]) else 1.0
            ax.loglog(t, e, "o-", lw=lw, ms=3, label=SHORT[m], color=COLORS[m])
        ax.axhline(r["reference"]["noise_mse"], color="k", ls=":", lw=0.8, label="ref. noise")
        ax.set_title(f"{r['scene']}, {r['variant']}", fontsize=9)
        ax.set_xticks(a.times)
        ax.set_xticklabels([f"{t:g}" for t in a.times])
        ax.minorticks_off()
        ax.set_xlabel("render time (s)", fontsize=8)
        ax.set_ylabel("MSE", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axs.flat)[n:]:
        ax.axis("off")
    axs.flat[0].legend(fontsize=6, loc="best")
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "curves.png"), dpi=110)
    plt.close(fig)
    made.append("curves.png")
    # Image grids with 10x squared-error insets (paper Figs. 16-18), at the table budget.
    for r in rows:
        imgs = images[(r["scene"], r["variant"])]
        ref = imgs["reference"]
        scale = 1.0 / max(np.percentile(ref, 99.5), 1e-6)
        cols_ = ["reference"] + [m for m in r["methods"] if m in imgs]
        fig, axs = plt.subplots(1, len(cols_), figsize=(2.3 * len(cols_), 2.3 * ref.shape[0] / ref.shape[1] + 0.5),
                                squeeze=False)
        for ax, m in zip(axs[0], cols_):
            ax.imshow(tonemap(imgs[m], scale * 2))
            title = LABELS[m]
            if m != "reference":
                run_ = [x for x in r["methods"][m] if x["budget_s"] == r["table_time"]][0]
                title += f"\nMSE {run_['mse']:.3g}, {run_['spp']:.0f} spp"
                err = np.clip(10 * (((imgs[m] - ref) * scale) ** 2).mean(-1), 0, 1)
                h, w = err.shape
                ins = ax.inset_axes([0.62, 0.0, 0.38, 0.38])
                ins.imshow(err[::2, ::2] if h > 60 else err, cmap="inferno", vmin=0, vmax=1)
                ins.set_xticks([]), ins.set_yticks([])
            ax.set_title(title, fontsize=7, fontweight="bold" if m == r["ours"] else "normal")
            ax.set_xticks([]), ax.set_yticks([])
        fig.suptitle(f"{r['scene']}, {r['label']}: equal time {r['table_time']:g} s "
                     f"(insets: 10x squared error, exposure-normalised)", fontsize=8)
        fig.tight_layout()
        name = f"grid_{r['scene']}_{r['variant']}.png"
        fig.savefig(os.path.join(a.out, name), dpi=110)
        plt.close(fig)
        made.append(name)
    for fr in frames:
        fig, ax = plt.subplots(1, 1, figsize=(4.5, 3))
        for m, v in fr["methods"].items():
            ax.semilogy([e["zoom"] for e in v["per_frame"]], [e["mse"] for e in v["per_frame"]], "o-", ms=3,
                        label=f"{SHORT[m]} (flicker {v['flicker_temporal_variance']:.3g})")
        ax.set_xlabel("zoom-out factor (camera distance)", fontsize=8)
        ax.set_ylabel(f"MSE at {fr['frame_time_s']:g} s", fontsize=8)
        ax.set_title(f"{fr['scene']}, {fr['variant']}: zoom-out", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        name = f"frames_{fr['scene']}.png"
        fig.savefig(os.path.join(a.out, name), dpi=110)
        plt.close(fig)
        made.append(name)
    return made


def bias_variance_table(rows):
    """Report lines: ours' error at the table budget split into bias^2 and variance per target shape
    and region (issue 21 item 5), against the original's variance (needs --repeats >= 2)."""
    out = []
    for r in rows:
        T = r["table_time"]
        pick = lambda m: next((x.get("split") for x in r["methods"].get(m, []) if x["budget_s"] == T), None)
        so, su = pick("original"), pick(r["ours"])
        if not so or not su:
            continue
        if not out:
            out = ["", "Bias and variance at the table budget, per target shape and region (near / middle / far "
                   "thirds of its pixels by footprint), x 1e-3, from the repeats: bias² = (mean over repeats - "
                   "reference)² less the mean's and the reference's variance; variance = one render's. **bias above**: "
                   "ours' bias² exceeds the original's variance at that budget, so no budget makes ours win there.", "",
                   "| scene | lighting | region | pixels | ours bias² | ours variance | original bias² | original variance | "
                   "ours bias² / original variance |", "|---|---|---|---|---|---|---|---|---|"]
        for k, u in su.items():
            o = so.get(k, {})
            ov = o.get("variance", 0.0)
            ratio = u["bias2"] / ov if ov > 0 else float("inf")
            out.append(f"| {r['scene']} | {r['variant']} | {k} | {u['pixels']} | {1e3 * u['bias2']:.3g} | "
                       f"{1e3 * u['variance']:.3g} | {1e3 * o.get('bias2', float('nan')):.3g} | {1e3 * ov:.3g} | "
                       f"{ratio:.2f}{' **bias above**' if ratio > 1 else ''} |")
    return out


def report(a, rows, models, frames, total_s, pngs, suite_file):
    tt = (f"**{a.table_time:g} s** (--table-time)" if a.table_time else
          "the smallest budget at which the original reaches 50 spp (the paper's regime: ~60 s for 50-100 spp), else the largest")
    L = ["# meso bench: equal-time error against run time", "",
         f"Suite `{os.path.relpath(suite_file, ROOT)}`; budgets {', '.join(f'{t:g}' for t in a.times)} s per render "
         f"(`meso render --time`, render time only); table budget per row: {tt}; threads "
         f"{a.threads or 'all'}; prefiltered estimator `{a.estimator}`; repeats {a.repeats}. "
         f"**Suite run time: {fmt_s(total_s)}** (models and references "
         f"{'partly cached' if any(m['cached'] for ms in models.values() for m in ms) or any(r['reference']['cached'] for r in rows) else 'computed'}).",
         "", f"Command: `meso bench {' '.join(a.argv)}`", ""]
    # Table 4.
    L += ["## Equal time: MSE x 1e-3 (paper Table 4)", "",
          "Ours = f'_low·R under direct light, f'_low·R_ir under GI. ratio = original / ours; "
          "win = the difference exceeds twice its standard error. Paper ratios: Table 4 (their scenes, ~60 s).", "",
          "texels/px: median (10th-90th percentile) footprint width in texels of the full-resolution map "
          "over the pixels that see a mapped shape (the paper's regime: at least 16). var/sample: ours' "
          "pixel variance per sample over the original's, from the repeats (target: at most 0.5). "
          "With repeats, MSEs are mean ± std over the repeats (seeds) and the ratio the ratio of the means ± the std of "
          "the per-repeat ratios.", "",
          "| scene | lighting | texels/px | budget | original | ours | ratio | paper ratio | meets paper | win (> 2 se) | var/sample ours/orig | ref. noise / ours | ratio, ref. noise removed |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        T = r["table_time"]
        c = [x for x in r["comparison"] if x["budget_s"] == T]
        if not c:
            continue
        c = c[0]
        pr = a.suite["scenes"][r["scene"]].get("paper_ratio")
        meets = "-" if pr is None else ("yes" if c["ratio"] >= pr else "**no**")
        tp = r.get("texels_per_pixel")
        tps = "-" if not tp else f"{tp['median']:.3g} ({tp['p10']:.2g}-{tp['p90']:.2g})"
        vr = c.get("var_per_sample_ratio")
        reps = {m: next((x["repeats"] for x in r["methods"][m] if x["budget_s"] == T), [])
                for m in ("original", r["ours"])}
        pm = lambda m: ("" if len(reps[m]) < 2 else
                        f" ± {1e3 * float(np.std([x['mse'] for x in reps[m]], ddof=1)):.2g}")
        ratios = [o["mse"] / u["mse"] for o, u in zip(reps["original"], reps[r["ours"]]) if u["mse"] > 0]
        rs = f" ± {float(np.std(ratios, ddof=1)):.2f}" if len(ratios) > 1 else ""
        L.append(f"| {r['scene']} | {r['variant']} | {tps} | {T:g} s | {1e3 * c['original_mse']:.4g}{pm('original')} | "
                 f"{1e3 * c['ours_mse']:.4g}{pm(r['ours'])} | "
                 f"{c['ratio']:.2f}x{rs} | {'-' if pr is None else f'{pr:g}x'} | {meets} | {'yes' if c['win'] else 'no'} | "
                 f"{'-' if vr is None else format(vr, '.2f')} | "
                 f"{r['reference']['noise_mse'] / max(c['ours_mse'], 1e-30):.2g} | "
                f"{'-' if c['ratio_ref_noise_removed'] is None else format(c['ratio_ref_noise_removed'], '.2f') + 'x'} |")
    L += ["", "Ratio original / ours at every budget (n.s.: the difference is within twice its standard error; "
          "worse: ours is significantly worse):", "",
          "| scene | lighting | " + " | ".join(f"{t:g} s" for t in a.times) + " |",
          "|---|---|" + "---|" * len(a.times)]
    for r in rows:
        L.append(f"| {r['scene']} | {r['variant']} | " +
                 " | ".join(f"{c['ratio']:.2f}x{'' if c['win'] else (' (worse)' if c.get('worse') else ' (n.s.)')}"
                            for c in r["comparison"]) + " |")
    L += bias_variance_table(rows)
    # Every method.
    L += ["", "## Every method: MSE x 1e-3 (relMSE) at each budget", ""]
    for r in rows:
        rn = r["reference"]
        L += [f"### {r['scene']}, {r['label']}", "",
              f"Reference: 2 x {rn['spp_per_half']} spp ({rn['seconds']:.0f} s{', cached' if rn['cached'] else ''}); "
              f"its noise MSE {1e3 * rn['noise_mse']:.3g}e-3 = "
              f"{rn['noise_mse'] / max(min(x['mse'] for runs in r['methods'].values() for x in runs), 1e-30):.2g} x "
              f"the smallest measured MSE.", "",
              "| method | " + " | ".join(f"{t:g} s" for t in a.times) + " | spp at the largest |",
              "|---|" + "---|" * (len(a.times) + 1)]
        for m, runs in r["methods"].items():
            lab = LABELS[m] + (" **(ours)**" if m == r["ours"] else "")
            L.append(f"| {lab} | " + " | ".join(f"{1e3 * x['mse']:.4g} ({x['relmse']:.3g})" for x in runs) +
                     f" | {runs[-1]['spp']:.0f} |")
        if "time_to_target" in r:
            L += ["", f"Time to reach the original's MSE at {r['table_time']:g} s ({1e3 * r['target_mse']:.4g}e-3): " +
                  "; ".join(f"{SHORT[m]} {'never within ' + format(a.times[-1], 'g') + ' s (bias or noise floor)' if v['bound'] == '>' else ('<= ' if v['bound'] == '<=' else '') + format(v['time_s'], '.3g') + ' s'}"
                            for m, v in r["time_to_target"].items())]
        L += ["", f"![{r['scene']} {r['variant']}](grid_{r['scene']}_{r['variant']}.png)", ""]
    L += ["## Error against time", "", "![curves](curves.png)", ""]
    # Table 3.
    L += ["## Storage and precomputation (paper Table 3)", "",
          "| scene | shape | resolution | tiling | original (KB) | base | downsampling | model (KB) | h_low | f'_low (lobes) | T | S+S_ir | "
          "precompute (s) | h_low + f'_low (s) | T/S (s) | T/S rounds | T/S memory (MB) | median rel. s.e. S / S_ir / T / T_ir |",
          "|" + "---|" * 18]
    for name, ms in models.items():
        for m in ms:
            t = m["table3"]
            L.append(f"| {name} | {m['shape']} | {t['resolution'][0]}x{t['resolution'][1]} | {t['tiling']} | "
                     f"{t['original_kb']:.0f} | {t['base']} | {t['downsampling']} | {t['model_kb']:.0f} | "
                     f"{t['h_low_kb']:.1f} | {t['flow_kb']:.0f} | {t['T_kb']:.1f} | {t['S_kb']:.0f} | "
                     f"{t['total_s']:.1f} | {t['hlow_flow_s']:.1f} | {t['TS_s']:.1f} | "
                     f"{t.get('TS_rounds') or '-'} | {t.get('estimator_mb', 0):.1f} | "
                     + " / ".join("-" if t.get(k) is None else format(t[k], ".3f")
                                  for k in ("S_rel_se_median", "S_ir_rel_se_median", "T_rel_se_median", "T_ir_rel_se_median"))
                     + " |")
    L += ["", "Original size: float32 heights of one tile of the map. S+S_ir: the angular tables of both fits. "
          "T and S are estimated together from the same paths (one time column), in rounds until every S table's median "
          "relative standard error reaches the target (`--target-error`, `--max-seconds`; issue 21 item 2). "
          "T/S memory: the estimator's sums.", ""]
    if frames:
        L += ["## Zoom-out sequences (flicker)", "",
              "Flicker: the variance over frames of each pixel's error (render - that frame's reference), averaged; "
              "mean-ratio spread: std over frames of mean(render) / mean(reference).", "",
              "| scene | method | frames | time per frame | mean MSE | flicker (temporal variance) | mean-ratio spread |",
              "|---|---|---|---|---|---|---|"]
        for fr in frames:
            for m, v in fr["methods"].items():
                L.append(f"| {fr['scene']} | {LABELS[m]} | {fr['frames']} | {fr['frame_time_s']:g} s | {v['mean_mse']:.4g} | "
                         f"{v['flicker_temporal_variance']:.4g} | {v['mean_ratio_std']:.3g} |")
            L += ["", f"![frames {fr['scene']}](frames_{fr['scene']}.png)", ""]
    L += ["## The scenes", ""]
    for r in rows:
        e = a.suite["scenes"][r["scene"]]
        L.append(f"* **{r['scene']}** ({r['label']}): {e.get('stand_in', '')}")
    with open(os.path.join(a.out, "report.md"), "w") as f:
        f.write("\n".join(L) + "\n")
