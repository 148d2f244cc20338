"""Figures of the benchmarks (matplotlib, written as PNG)."""

import math
import os

import numpy as np


def save_figure(fig, path):
    """``fig`` at ``path`` (its format by the suffix), written whole (volmc.outputs)."""
    from ..outputs import written_whole
    with written_whole(path, os.path.splitext(str(path))[1]) as tmp:
        fig.savefig(tmp, dpi=110)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def heatmaps(report, path):
    """Per estimator: log10 of 1/(MSE x lookups) over target T x majorant tightness,
    geometric mean over the 1-D profiles (zero-error cases shown at the colour maximum, cases
    without a measure left out). MSE, not variance, so the biased ray marcher is charged for
    its bias."""
    from ..techniques import ESTIMATORS
    names = [n for n in report["estimators"] if not ESTIMATORS[n].homogeneous_only]
    Ts = sorted({r["target_T"] for r in report["profiles"]})
    ks = sorted({r["tightness"] for r in report["profiles"]})
    grids = {}
    for n in names:
        acc = np.zeros((len(ks), len(Ts)))
        cnt = np.zeros_like(acc)
        for r in report["profiles"]:
            if n not in r["results"]:
                continue
            e = r["results"][n]["eff_mse_lookups"]
            if math.isnan(e):   # no measure: a noisy estimate at no lookup, or non-finite
                continue
            e = 1e12 if math.isinf(e) else e
            i, j = ks.index(r["tightness"]), Ts.index(r["target_T"])
            acc[i, j] += math.log10(max(e, 1e-12))
            cnt[i, j] += 1
        grids[n] = acc / np.maximum(cnt, 1)
    vmin = min(g.min() for g in grids.values())
    vmax = min(max(g.max() for g in grids.values()), vmin + 8)

    def axes(ax):
        ax.set_xticks(range(len(Ts)), [f"{t:g}" for t in Ts], fontsize=7)
        ax.set_yticks(range(len(ks)), [f"{k:g}" for k in ks], fontsize=7)
        ax.set_xlabel("target transmittance", fontsize=8)
        ax.set_ylabel("mean mu / majorant", fontsize=8)
    _estimator_panels(report, grids, (vmin, vmax), axes, "log10 1 / (MSE x lookups)",
                      "Efficiency over the 1-D profile sweep (geometric mean over 5 profiles)",
                      path, (3.6, 3.3))


def _estimator_panels(report, grids, limits, axes, colour_label, title, path, size):
    """One image panel per estimator ({name: 2-D array}) on a shared colour scale
    ``limits``, four to a row; ``axes(ax)`` labels each panel's axes."""
    plt = _plt()
    names = list(grids)
    cols = 4
    rows = -(-len(names) // cols)
    fig, axs = plt.subplots(rows, cols, figsize=(size[0] * cols, size[1] * rows),
                            squeeze=False, constrained_layout=True)
    for ax, n in zip(axs.ravel(), names):
        im = ax.imshow(grids[n], origin="lower", vmin=limits[0], vmax=limits[1],
                       cmap="viridis", aspect="auto")
        axes(ax)
        ax.set_title(n + ("" if report["unbiased"][n] else " (biased)"), fontsize=9)
    for ax in axs.ravel()[len(names):]:
        ax.axis("off")
    fig.colorbar(im, ax=axs.ravel().tolist(), label=colour_label)
    fig.suptitle(title)
    save_figure(fig, path)
    plt.close(fig)


def convergence_plots(report, path_cost, path_time):
    """Variance of the mean against lookups, and RMSE against time, for each grid-ray case,
    with the 1/N (variance) and 1/sqrt(t) (RMSE) reference slopes."""
    plt = _plt()
    rows = report["grids"]
    if not rows:
        return
    for path, xkey, ykey, slope, xlabel, ylabel in (
            (path_cost, "lookups", "variance", -1.0, "density lookups per estimate",
             "variance of the mean"),
            (path_time, "seconds", "rmse", -0.5, "OpenCL time per estimate (s)", "RMSE")):
        cols = min(3, len(rows))
        n_rows = -(-len(rows) // cols)
        fig, axs = plt.subplots(n_rows, cols, figsize=(5 * cols, 4 * n_rows), squeeze=False)
        for ax in axs.ravel()[len(rows):]:
            ax.axis("off")
        for ax, row in zip(axs.ravel(), rows):
            for n, r in row["results"].items():
                pts = [c for c in r["convergence"] if c[ykey] == c[ykey] and c[ykey] > 0]
                if not pts:
                    continue
                x = [c[xkey] for c in pts]
                y = [c[ykey] for c in pts]
                ax.loglog(x, y, "o-" if report["unbiased"][n] else "x--", ms=3, label=n)
            xs = np.array(ax.get_xlim())
            y0 = ax.get_ylim()[1] * 0.5
            ax.loglog(xs, y0 * (xs / xs[0]) ** slope, "k:", lw=1,
                      label="1/N" if slope == -1 else "1/sqrt(t)")
            ax.set_title(f"{os.path.basename(row['scene'])}: {row['rays']}", fontsize=9)
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.legend(fontsize=7)
        fig.tight_layout()
        save_figure(fig, path)
        plt.close(fig)


def render_convergence_plot(report, path, max_lines=12):
    """`volmc bench render`: RMSE against wall time per configuration (log-log), the best
    ``max_lines`` volmc configurations plus the peers, with a 1/sqrt(t) slope for reference."""
    from .convergence import PEER_BACKENDS
    plt = _plt()
    rows = sorted(report["results"], key=lambda r: r["mse_seconds"])
    keep = [r for r in rows if r["backend"] not in PEER_BACKENDS][:max_lines]
    keep += [r for r in rows if r["backend"] in PEER_BACKENDS]
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for r in keep:
        pts = sorted((p for p in r["points"] if p["rmse"] > 0), key=lambda p: p["seconds"])
        style = (dict(color="k", lw=2.2, marker="s") if r["backend"] == "mitsuba" else
                 dict(color="tab:orange", lw=2.2, marker="D") if r["backend"] == "cycles" else
                 dict(lw=1.2, marker="o", ms=3))
        ax.loglog([p["seconds"] for p in pts], [p["rmse"] for p in pts],
                  label=f"{r['name']} ({r['time_to_equal_error_vs_best_volmc']:.2f}x)", **style)
    xs = np.array(ax.get_xlim())
    best = keep[0]
    ax.loglog(xs, np.sqrt(best["mse_seconds"] / xs), "k:", lw=1, label="1/sqrt(t) through best")
    w, h = report["resolution"]
    ax.set_title(f"{os.path.basename(str(report['scene']))}, {w}x{h}: RMSE against wall time "
                 f"(time to equal error vs best in brackets)", fontsize=9)
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("RMSE against the reference")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def variance_sampler_plot(full, path):
    """`volmc bench variance`: RMSE against spp (log-log) of the samplers (independent =
    the plain configuration, stratified, sobol: variance.SAMPLER_CURVES) per scene, every
    point with its least-squares line (slope in the legend) and an N^-1/2 guide through the
    plain configuration's first level."""
    from .variance import PLAIN, SAMPLER_CURVES, loglog_slope, scene_names
    plt = _plt()
    reports = full["scenes"]
    fig, axs = plt.subplots(1, len(reports), figsize=(5 * len(reports), 4.2), squeeze=False)
    for ax, rep, name in zip(axs[0], reports, scene_names(reports)):
        rows = {r["label"]: r for r in rep["results"]}
        for legend, label in SAMPLER_CURVES:
            if label not in rows:
                continue
            pts = [p for p in rows[label]["points"] if p["rmse"] > 0]
            n = np.array([p["spp"] for p in pts], float)
            e = np.array([p["rmse"] for p in pts])
            slope = loglog_slope(n, e)
            line = ax.loglog(n, e, "o", ms=3, alpha=0.6)[0]
            if slope is not None:
                a = float(np.mean(np.log(e) - slope * np.log(n)))
                xs = np.array([n.min(), n.max()])
                ax.loglog(xs, np.exp(a) * xs ** slope, "-", color=line.get_color(),
                          label=f"{legend} (slope {slope:.2f})")
            else:
                line.set_label(legend)
        plain = [p for p in rows[PLAIN]["points"] if p["rmse"] > 0]
        if plain:
            n0 = min(p["spp"] for p in plain)
            e0 = math.exp(float(np.mean([math.log(p["rmse"]) for p in plain
                                         if p["spp"] == n0])))
            xs = np.array(sorted({p["spp"] for p in plain}), float)
            ax.loglog(xs, e0 * (xs / n0) ** -0.5, "k:", lw=1, label="N^-1/2")
        w, h = rep["resolution"]
        # Ticks at the spp levels themselves: log-axis minor labels overlap on a short ladder.
        from matplotlib.ticker import NullLocator
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xticks(rep["spp_levels"], [str(n) for n in rep["spp_levels"]])
        ax.set_title(f"{name}, {w}x{h}", fontsize=9)
        ax.set_xlabel("samples per pixel")
        ax.set_ylabel("RMSE against the reference")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _map_grid(maps, value):
    """[n_tightness, n_tau_bar] array of value(bin) (NaN where the bin was not measured)."""
    nt = len(maps["tau_bar_edges"]) - 1
    nk = len(maps["tightness_edges"]) - 1
    out = np.full((nk, nt), np.nan)
    for b in maps["bins"]:
        v = value(b)
        if v is not None:
            out[b["j"], b["i"]] = v
    return out


def _map_axes(ax, maps):
    te, ke = maps["tau_bar_edges"], maps["tightness_edges"]
    ax.set_xticks(np.arange(len(te)) - 0.5, [f"{t:.2g}" for t in te], fontsize=6)
    ax.set_yticks(np.arange(len(ke)) - 0.5, [f"{k:.1f}" for k in ke], fontsize=6)
    ax.set_xlabel("majorant optical depth sigma_maj L", fontsize=8)
    ax.set_ylabel("tightness tau / (sigma_maj L)", fontsize=8)


def segment_maps(report, path):
    """Per estimator: its 1/(MSE x time) relative to the best unbiased estimator's in each
    bin of (majorant optical depth, tightness) of the replayed majorant segments
    (segment_maps.py), log10: 0 where it wins, -1 at a tenth. Relative, because a bin's
    absolute efficiency scales with 1/T^2 and would swamp the comparison. Blank bins hold
    too few segments."""
    from ..techniques import ESTIMATORS
    maps = report["maps"]
    names = [n for n in report["estimators"] if not ESTIMATORS[n].homogeneous_only]

    def best(b):
        e = [r["eff_mse_time"] for n, r in b["results"].items() if report["unbiased"][n]]
        return max(e) if e else None

    def rel(n):
        def f(b):
            r, top = b["results"].get(n), best(b)
            if r is None or top is None or not top > 0:
                return None
            if top == math.inf:
                return 0.0 if r["eff_mse_time"] == math.inf else -3.0
            return math.log10(max(r["eff_mse_time"], 1e-300) / top)
        return f
    grids = {n: _map_grid(maps, rel(n)) for n in names}
    _estimator_panels(report, grids, (-3.0, 1.0), lambda ax: _map_axes(ax, maps),
                      "log10 of 1 / (MSE x time) over the best unbiased estimator's",
                      "Efficiency over the majorant segments of replayed render segments, "
                      "relative to each bin's winner", path, (3.8, 3.1))


def winner_map(report, path):
    """The most efficient unbiased estimator per bin of (majorant optical depth, tightness),
    by 1/(variance x lookups) and by 1/(MSE x time). When the renderer has the "auto" rule,
    each bin is labelled with the rule's majority choice over the bin's segments, and a last
    panel shows the rule's regions over (majorant optical depth, sigma_min / sigma_maj)."""
    plt = _plt()
    from matplotlib.colors import ListedColormap
    maps = report["maps"]
    names = sorted({b[k] for b in maps["bins"] for k in ("winner_var_lookups",
                                                          "winner_mse_time") if b.get(k)})
    regions = maps.get("auto_regions")
    if regions:
        names = sorted(set(names) | {c for row in regions["choice"] for c in row})
    if not names:
        return
    cmap = ListedColormap(plt.get_cmap("tab10").colors[:len(names)])
    panels = [("winner_var_lookups", "by 1 / (variance x lookups)"),
              ("winner_mse_time", "by 1 / (MSE x time)")]
    n_ax = len(panels) + (1 if regions else 0)
    fig, axs = plt.subplots(1, n_ax, figsize=(5.2 * n_ax, 4.2), squeeze=False)
    for ax, (key, title) in zip(axs[0], panels):
        g = _map_grid(maps, lambda b: names.index(b[key]) if b.get(key) else None)
        ax.imshow(g, origin="lower", cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5,
                  aspect="auto")
        _map_axes(ax, maps)
        ax.set_title(f"most efficient unbiased estimator {title}", fontsize=8)
        for b in maps["bins"]:
            label = f"n={b['n_segments']}" if b["results"] else ""
            if b.get("auto"):
                label = _short(b["auto"]) + ("\n" + label if label else "")
            if label:
                ax.text(b["i"], b["j"], label, ha="center", va="center", fontsize=5.5)
    if regions:
        ax = axs[0][-1]
        g = np.array([[names.index(c) for c in row] for row in regions["choice"]], float)
        t, q = regions["tau_bar"], regions["bound_ratio"]
        ax.pcolormesh(t, q, g, cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5, shading="nearest")
        ax.set_xscale("log")
        ax.set_xlabel("majorant optical depth sigma_maj L", fontsize=8)
        ax.set_ylabel("sigma_min / sigma_maj", fontsize=8)
        ax.set_title(f"the auto rule's choice (L = {regions['length']:.3g})", fontsize=8)
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(k)) for k in range(len(names))]
    fig.legend(handles, [f"{n} ({_short(n)})" for n in names], loc="lower center",
               ncol=len(names), fontsize=7)
    note = ("\nletters: the auto rule's majority choice per bin on shadow rays of scattering "
            "paths (a lone transmittance: unbiased ray marching)" if maps.get("auto") else "")
    fig.suptitle("Winner over the majorant segments of replayed render segments" + note,
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 0.95))
    save_figure(fig, path)
    plt.close(fig)


def _short(name):
    """A two-letter label of an estimator for the map cells."""
    return "".join(w[0] for w in name.split("_")).upper() if "_" in name else name[:2].upper()
