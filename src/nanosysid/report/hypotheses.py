"""The hypotheses stage's report: the low-frequency roll/pitch torque's hypotheses, each with its
coefficients, held-out share, hover check and repeatability, what the flights name and exclude;
and the hypothesis_worlds stage's report, the tests judged on simulated worlds of one effect each."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from nanosysid import hypotheses

__all__ = ["headline", "hypotheses_markdown", "worlds_markdown", "WORLDS_TITLE"]


def _pm(mean: Sequence[float], half: Sequence[float], params: Sequence[str]) -> str:
    parts = []
    for m, h, p in zip(mean, half, params):
        unit = p.split("[", 1)[1].rstrip("]") if "[" in p else ""
        name = p.split(" [", 1)[0]
        parts.append(f"{name} = {m:.3g} ± {h:.2g}{' ' + unit if unit and unit != '-' else ''}")
    return "; ".join(parts)


def headline(result: Mapping[str, Any]) -> str:
    """One sentence: what the flights' roll/pitch torque below the cutoff is, by the tests."""
    named = result["named"]
    recs = result["hypotheses"]
    if not named:
        return "No hypothesis explains the roll/pitch torque below the cutoff, and what is left repeats with the reference."
    if named == [hypotheses.AIR]:
        return ("No hypothesis of the state or the inputs explains the roll/pitch torque below the cutoff, and it "
                "does not repeat between runs of one reference: the air.")
    first = named[0]
    tied = [n for n, r in recs.items() if r.get("status") == "not told apart"]
    s = (f"`{' + '.join(named)}` explain{'' if len(named) > 1 else 's'} {100 * result['share']:.0f} % of the "
         "roll/pitch torque below the cutoff held out")
    if tied:
        s += f" (`{first}` not told apart from {', '.join(f'`{t}`' for t in tied)})"
    excluded = [n for n, r in recs.items() if r.get("status") == "excluded"]
    if excluded:
        s += f"; excluded: {', '.join(f'`{n}`' for n in excluded)}"
    return s + "."


def hypotheses_markdown(result: Mapping[str, Any], *, source: str, cutoff: float,
                        weight: float | None = None) -> str:
    """The report: the table of hypotheses, the selection's rounds, the hover torque, the take-off
    holds (where measured) and the repeatability; ``weight`` (N), the vehicle's m g, turns an
    offset into the torque it makes in hover."""
    recs = result["hypotheses"]
    hover = result["hover"]
    L = [f"# The low-frequency roll/pitch torque: its hypotheses, tested apart ({source})", "",
         f"The roll/pitch torque the rotor model misses (measured `J dω/dt + ω × Jω` minus the mixer's), low-passed "
         f"at {cutoff:g} Hz (zero phase), on the training flights. Each hypothesis: its coefficients fitted to each "
         "flight alone (mean and 95 % interval over the flights, independent repeats); its share of the residual's "
         "power held out (fitted on the other references' flights); the hover check (the share of the residual torque "
         f"where the vehicle barely moves, |v_xy| < {hypotheses.HOVER_SPEED:g} m/s and |ω_xy| < "
         f"{hypotheses.HOVER_RATE:g} rad/s, that it reproduces); and how well what it explains, and what it leaves, "
         "correlate between runs of one reference (1: repeats exactly; 0: not at all).", "",
         f"**Verdict.** {headline(result)}", "",
         "| hypothesis | coefficients (95 % from flights) | held out | hover reproduced | explained repeats | "
         "left repeats | verdict |", "|---|---|---|---|---|---|---|"]
    explained, left = result["repeats"]["explained"], result["repeats"]["left"]

    def f(x, pct=True):
        return "–" if x is None else (f"{100 * x:.0f} %" if pct else f"{x:.2f}")

    for name, r in recs.items():
        if not r.get("testable"):
            L.append(f"| `{name}` | – | – | – | – | – | untestable: {r.get('why', '')} |")
            continue
        coef = _pm(r["mean"], r["half_width"], r["params"])
        status = r.get("status", "")
        why = r.get("why", "")
        L.append(f"| `{name}` | {coef} | {f(r['share'])} | {f(hover['reproduced'].get(name))} | "
                 f"{f(explained.get(name), False)} | {f(left.get(name), False)} | {status}{': ' + why if why else ''} |")
    air = result["air"]
    L += [f"| air | – | – | – | – | {f(air.get('correlation'), False)} | {air['status']}"
          f"{': ' + air['why'] if air.get('why') else ''} |", ""]
    L += ["## The selection", "",
          f"Forward selection over held-out shares: a hypothesis joins when it adds at least "
          f"{100 * hypotheses.MIN_SHARE:.0f} % (the first) or {100 * hypotheses.MIN_GAIN:.0f} % (a later one) held out, "
          "one of its coefficients' intervals excludes zero, its coefficients are physically possible (the library "
          "entry's signs, bound and shape, as discovery judges them: the rotors' slow history fits the controller's "
          "answer to any slow torque, a drag moment's too, but only with shares no lag of a rotor's wrench has), and "
          "what it explains repeats between runs of one "
          f"reference (correlation ≥ {hypotheses.REPEAT:g}: a fit that follows the controller's answer to a "
          "disturbance does not). Gains within "
          f"{100 * hypotheses.TIE:.0f} % of the best are not told apart; the one with the fewest coefficients joins.", ""]
    for k, rd in enumerate(result["rounds"], 1):
        gains = ", ".join(f"`{n}` {100 * g['gain']:+.1f} %{'' if g['significant'] else ' (n.s.)'}"
                          f"{'' if g['repeats'] else ' (no repeat)'}{' (not possible)' if g.get('implausible') else ''}"
                          for n, g in rd["gains"].items())
        L.append(f"- round {k}: {('`' + rd['added'] + '` joins') if rd['added'] else 'none joins'}. Gains: {gains}.")
    L += ["", "## The hover check", ""]
    if hover["flights"]:
        mean = " / ".join(f"{1e3 * m:.3f} ± {1e3 * h:.3f}" for m, h in zip(hover["mean"], hover["half_width"]))
        L.append(f"Residual torque in hover, mean over {hover['flights']} flights (tau_x / tau_y, mN·m, 95 %): {mean}; "
                 f"{'it differs from zero' if hover['significant'] else 'it does not differ from zero'}. A drag moment "
                 "vanishes in hover; a centre-of-mass offset does not. Share of it reproduced: "
                 + ", ".join(f"`{n}` {f(v)}" for n, v in hover["reproduced"].items()) + ".")
    else:
        L.append("No flight holds enough hover samples for the check.")
    hold = recs.get(hypotheses.HOLD)
    if hold:
        L += ["", "## The centre of mass, flight by flight, from the take-off hold", "",
              "Each flight's take-off hold (outside the scored segment) gives the offset that trims its rotors in "
              "hover (a per-rotor spread acts alike there). Taken as known in flight: held-out share "
              f"{f(hold['share'])}, hover torque reproduced {f(hover['reproduced'].get(hypotheses.HOLD))}"
              + (f"; with the named hypotheses refitted on what it leaves, {f(hold.get('with_named'))} explained "
                 f"({100 * hold.get('gain', 0):+.1f} % against theirs alone), hover torque reproduced "
                 f"{f(hover['reproduced'].get('named+hold'))}" if 'with_named' in hold else "") + ".", "",
              "| flight | r_x (mm) | r_y (mm) |", "|---|---|---|"]
        for name, h in hold["per_flight"].items():
            (rx, ry), (hx, hy) = h["offset"], h["half_width"]
            L.append(f"| {name} | {1e3 * rx:.2f} ± {1e3 * hx:.2f} | {1e3 * ry:.2f} ± {1e3 * hy:.2f} |")
        n = len(hold["per_flight"])
        L += ["", f"Mean over flights: r_x {1e3 * hold['mean'][0]:.2f} ± {1e3 * hold['half_width'][0]:.2f} mm, "
              f"r_y {1e3 * hold['mean'][1]:.2f} ± {1e3 * hold['half_width'][1]:.2f} mm (95 % from the flights; each "
              f"flight's ± from its hold's quarters). The holds of {len(hold['moved'])} of {n} flights exclude that "
              "mean from their own interval: "
              + ("the offset moves between flights, as a battery re-seated between flights moves it." if hold["moved"] else
                 "the offset stays put between flights.")
              + (f" An offset of 1 mm makes {1e3 * weight * 1e-3:.2f} mN·m in hover (m g d)." if weight else "")]
    return "\n".join(L) + "\n"


WORLDS_TITLE = "# The low-frequency torque's hypothesis tests on simulated worlds whose truth is hidden"


def worlds_markdown(worlds: Mapping[str, Any], *, cutoff: float) -> str:
    """The hypothesis_worlds stage's report: per family of worlds, what the tests named and
    whether the family's requirement and the ``cg_offset`` interval's coverage hold
    (:func:`nanosysid.hypothesis_worlds.summarize`)."""
    L = [WORLDS_TITLE, "",
         "Worlds with one of nature's effects alone (strength 0.3 to 3 times its record's), every training "
         f"trajectory flown twice; the tests (the roll/pitch torque low-passed at {cutoff:g} Hz) see the flights "
         "only.", "",
         "| world family | worlds | requirement | met | named (worlds) | cg_offset interval covers the truth |",
         "|---|---|---|---|---|---|"]
    for fam, rec in worlds["families"].items():
        cov = rec.get("coverage")
        cov_s = f"{cov['covered']}/{cov['worlds']}" if cov else "–"
        named = ", ".join(f"{n} {k}" for n, k in rec["named"].items())
        L.append(f"| {fam} | {rec['worlds']} | {rec['requirement']} | {rec['met']}/{rec['worlds']} | {named} | "
                 f"{cov_s} |")
    return "\n".join(L) + "\n"
