"""One path step of one lane: counter-based random numbers, platelet and interface scattering, next-event estimation and shadow rays."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..brdf._platelet import cosine_hemisphere
from ..instrument._single_scatter import _orthonormal_basis
from ..optics._fresnel import fresnel_dielectric
from ..optics._interface import reflect, refract, sample_facet_normal, sample_visible_facet, seen_through_facet
from ._options import _BIG, TracerOptions
from ._scene import _WAVY_MAX_TAN_IN, _WAVY_MIN_COS_IN, _cone, _face_normal, _refract_in, _rotz, _Scene, _to_local, _traverse

# One step of one lane


_NU = 8  # uniforms per step besides the per-detector aperture jitter and shadow roulette


def _mix(x):
    """32-bit integer finaliser (Wellons' lowbias32): full avalanche in five cheap operations."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def _ray_hash(seed, rid, step):
    """Counter-based 32-bit state of (seed, ray id, step): the ray's random stream at this step."""
    r = rid.astype(jnp.uint32) if rid.dtype.itemsize <= 4 else (rid.astype(jnp.uint64) ^ (rid.astype(jnp.uint64) >> 32)).astype(jnp.uint32)
    h = _mix(seed ^ _mix(r * jnp.uint32(0x9E3779B9) + jnp.uint32(0x632BE5AB)))
    return _mix(h + _mix(step.astype(jnp.uint32) + jnp.uint32(0x85EBCA6B)))


def _uniforms(h, count: int, dtype):
    """`count` uniforms in [0, 1) from a ray-step state h (24 random bits each)."""
    k = jnp.arange(1, count + 1, dtype=jnp.uint32) * jnp.uint32(0x9E3779B9)
    bits = _mix(h + k)
    return ((bits >> 8).astype(dtype) + 0.5) * (1.0 / 16777216.0)


def _key_from(h):
    """A raw threefry key for the platelet BRDF's own sampler."""
    return jnp.stack([_mix(h ^ jnp.uint32(0xA511E9B3)), _mix(h ^ jnp.uint32(0x63D83595))])


def _new_ray_uniforms(sc: _Scene) -> int:
    return 7 if sc.wavy else 5


def _source(sc: _Scene, rid):
    """Source index of ray `rid` (rays are dealt to the sources in turn, along the scene's wheel)."""
    return sc.wheel[(rid % sc.wheel.shape[0]).astype(jnp.int32)]


def _new_ray(sc: _Scene, u, dtype, randomize_azimuth: bool = True, src=0):
    """Position, direction, weight T, top reflection 1 − T and rotation (cos, sin) of a fresh ray from uniforms u.

    The ray enters through a clearcoat facet m (flat: m = z; wavy: drawn from the visible-normal
    density of the illumination direction).
    """
    phi = 2.0 * jnp.pi * u[4] if randomize_azimuth else jnp.zeros((), dtype)
    c, s = jnp.cos(phi), jnp.sin(phi)
    w_air = _cone(sc.illum_air[src], sc.illum_cos_alpha, u[2], u[3])
    w_air = _rotz(w_air, c, s)
    if sc.wavy:
        mf = sample_visible_facet(w_air, sc.slope_sd, u[5], u[6])
        t, cos_i = refract(-w_air, mf, 1.0 / sc.n)
        d = t / jnp.linalg.norm(t)
    else:
        cos_i = w_air[2]
        d = -_refract_in(w_air, sc.n)
    Ri = fresnel_dielectric(cos_i, 1.0, sc.n)[2]
    pos = jnp.stack([u[0] * sc.tile[0], u[1] * sc.tile[1], sc.h_b - sc.eps])
    cast = lambda x: jnp.asarray(x).astype(dtype)  # noqa: E731
    return cast(pos), cast(d), cast(1.0 - Ri), cast(Ri), cast(c), cast(s)


def _exit_density(q_in, cos_air, cos_in, n):
    """Density per air steradian of an exit direction whose internal direction had density q_in
    per internal steradian (refraction: n² cosθ_in dω_in = cosθ_air dω_air)."""
    return q_in * cos_air / (n**2 * jnp.maximum(cos_in, 1e-12))


def _has_delta(brdf) -> bool:
    """Whether the BRDF's sampler can return its delta (mirror) direction with finite weight."""
    return bool(brdf.is_delta) or getattr(brdf, "coherent", None) == "delta"


def _projected_pdfs(sc: _Scene, hit, wi_loc, wo_loc):
    """Sampling densities per projected solid angle at a vertex, forward (ω_i → ω_o) and reverse (ω_o → ω_i).

    The primer's cosine sampling gives 1/π both ways; a platelet face its BRDF's `pdf`.
    """
    wi_b = jnp.broadcast_to(wi_loc, wo_loc.shape)
    cos_i = jnp.maximum(wi_b[..., 2], 1e-12)
    cos_o = jnp.maximum(wo_loc[..., 2], 1e-12)
    fwd = sc.brdf.pdf(wi_b, wo_loc).astype(cos_i.dtype) / cos_o
    rev = sc.brdf.pdf(wo_loc, wi_b).astype(cos_i.dtype) / cos_i
    return jnp.where(hit, fwd, 1.0 / jnp.pi), jnp.where(hit, rev, 1.0 / jnp.pi)


def _log(x):
    return jnp.log(jnp.maximum(x, 1e-30))


def _reverse_weight(sc: _Scene, src, hit, first, lg, wi_loc, wo_loc_j, w_in):
    """Balance-heuristic weight of this vertex's NEE toward each detector against the reverse tracer.

    For a path x_1 … x_k closed by NEE at x_k, forward (beam → x_1, sampled directions, NEE x_k →
    detector) and reverse (detector beam → x_k, sampled directions, NEE x_1 → source) path densities
    have the ratio ρ = (cos_k,det |z_L|) / (cos_1,in |z_D|) · Π_{i=2..k} q̃_rev,i / Π_{i=1..k−1} q̃_fwd,i
    (q̃ per projected solid angle; the beams' projected-area densities give the cosines, the
    geometric terms cancel). With c = reverse / forward rays, the forward weight is 1 / (1 + c ρ);
    the reverse tracer computes 1 / ρ for the same path, so the two weights sum to one.
    """
    _, rev_j = _projected_pdfs(sc, hit, wi_loc, wo_loc_j)
    cos_in = jnp.maximum(wi_loc[2], 1e-12)
    log_rho = (sc.log_reverse_share[src] + _log(sc.illum_in_z[src]) - _log(w_in[:, 2]) + _log(wo_loc_j[:, 2])
               + jnp.where(first, -_log(cos_in), lg + _log(rev_j)))
    return jax.nn.sigmoid(-jnp.clip(log_rho, -80.0, 80.0))


def _update_log_ratio(sc: _Scene, hit, first, lg, wi_loc, wo_loc, wo_pr):
    """Running log of (1 / cos_1,in) Π_{i≥2} q̃_rev,i / Π q̃_fwd,i after sampling this vertex's direction."""
    wo = jnp.where(hit, wo_loc, wo_pr)
    fwd, rev = _projected_pdfs(sc, hit, wi_loc, wo)
    cos_in = jnp.maximum(wi_loc[2], 1e-12)
    return jnp.where(first, -_log(cos_in), lg + _log(rev)) - _log(fwd)  # finite: `_log` floors its argument


def _step_one(sc: _Scene, opt: TracerOptions, ray, key, single):
    """Advance one lane by one step: its pending shadow rays and its ray. Returns (lane, tally)."""
    pos, d, w, alive, cph, sph, nstep, nev, rid, spec_last, q_last, lg, sh_org, sh_dir, sh_lim, sh_val = ray
    dtype = pos.dtype
    m = sc.det_air.shape[0]
    has_delta = _has_delta(sc.brdf)
    u = _uniforms(key, _NU + 3 * m + (2 + 2 * m if sc.wavy else 0), dtype)
    uf = u[_NU + 3 * m :]  # facet draws of a wavy coat: 2 at the top, 2 per detector
    kb = _key_from(key)
    nee = jnp.zeros(m, dtype)  # NEE is scored by `_shadows` one step later

    # --- traversal to the next event
    dz = d[2]
    t_slab = jnp.where(dz > 0, (sc.h_b - pos[2]) / jnp.where(dz > 0, dz, 1.0),
                       jnp.where(dz < 0, -pos[2] / jnp.where(dz < 0, dz, -1.0), _BIG))
    t_slab = jnp.maximum(t_slab, 0.0).astype(dtype)
    tb, jb, sb, treach, fin = _traverse(sc, pos, d, t_slab, False, sc.max_cells)

    hit = alive & fin & (tb < t_slab)
    top = alive & fin & ~hit & (dz > 0)
    bottom = alive & fin & ~hit & ~(dz > 0)
    moving = alive & ~fin
    event = hit | bottom
    first = nev == 0

    # --- scattering event: platelet face (BRDF) or primer (Lambert)
    x_hit = pos + tb * d
    nf, side = _face_normal(sc, jb, sb, x_hit, d)
    x_bot = jnp.concatenate([pos[:2] + t_slab * d[:2], jnp.zeros(1, dtype)])
    ez = jnp.array([0.0, 0.0, 1.0], dtype)
    n_ev = jnp.where(hit, nf, ez)
    x_ev = jnp.where(hit, x_hit, x_bot)
    t1, t2 = _orthonormal_basis(n_ev)
    wi_loc = _to_local(-d, t1, t2, n_ev)
    wo_loc, s_w = sc.brdf.sample(kb, wi_loc)
    wo_loc = wo_loc.astype(dtype)
    s_w = jnp.where(jnp.isfinite(s_w), s_w, 0.0).astype(dtype)
    wo_pl = wo_loc[0] * t1 + wo_loc[1] * t2 + wo_loc[2] * n_ev
    wo_pr = cosine_hemisphere(u[5], u[6])  # the Lambertian primer
    wo = jnp.where(hit, wo_pl, wo_pr)
    wo = wo / jnp.maximum(jnp.linalg.norm(wo), 1e-30)
    factor = jnp.where(hit, s_w, sc.albedo)
    if opt.edges == "absorb":
        factor = jnp.where(hit & side, 0.0, factor)
    # was the sampled direction the BRDF's delta (mirror / coherent) branch?
    if sc.brdf.is_delta:
        spec = hit
    elif has_delta:
        mirror = wi_loc * jnp.array([-1.0, -1.0, 1.0], dtype)
        spec = hit & (jnp.sum((wo_loc - mirror) ** 2) < 1e-8)
    else:
        spec = jnp.zeros((), bool)
    omega = 2.0 * jnp.pi * (1.0 - sc.det_cos_alpha)  # detector cone solid angle (0: point detectors)

    def sampling_pdf(wo_l, cos_primer):  # per internal sr: platelet BRDF's continuous branches, or the primer's cosine
        return jnp.where(hit, sc.brdf.pdf(jnp.broadcast_to(wi_loc, wo_l.shape), wo_l).astype(dtype), cos_primer / jnp.pi)

    if sc.mis:
        q_ev = sampling_pdf(wo_loc, wo_pr[2])

    # --- next-event estimation: this event's shadow rays are traced in the next step
    origin = x_ev + sc.eps * n_ev
    origin = jnp.concatenate([origin[:2], jnp.clip(origin[2:], sc.eps, sc.h_b)])
    # the non-delta part of every event (primer, platelet lobe)
    uj = u[_NU : _NU + 2 * m].reshape(m, 2)
    w_air = _cone(sc.det_air, sc.det_cos_alpha, uj[:, 0], uj[:, 1])
    w_air = _rotz(w_air, cph, sph)
    if sc.wavy:  # the detector sees the visible facets m_j: v_j T(m_j) L_in(refraction of ω_j at m_j) / n²
        mj = sample_facet_normal(sc.slope_sd, uf[2 : 2 + m], uf[2 + m : 2 + 2 * m])
        w_in, To = seen_through_facet(w_air, mj, sc.n, sc.slope_sd)
        To = jnp.where(w_in[:, 2] > _WAVY_MIN_COS_IN, To, 0.0)  # bounds the shadow rays' travel (no weight there)
        w_in = w_in.at[:, 2].set(jnp.maximum(w_in[:, 2], _WAVY_MIN_COS_IN))
    else:
        w_in = _refract_in(w_air, sc.n)
        To = 1.0 - fresnel_dielectric(w_air[:, 2], 1.0, sc.n)[2]
    wo_loc_j = _to_local(w_in, t1[None], t2[None], n_ev[None])
    f_pl = sc.brdf.evaluate(jnp.broadcast_to(wi_loc, (m, 3)), wo_loc_j).astype(dtype)
    f = jnp.where(hit, f_pl, sc.albedo / jnp.pi)
    cos_o = jnp.maximum(wo_loc_j[:, 2], 0.0)
    val = jnp.pi * w * f * cos_o * To / (sc.n**2 * w_in[:, 2])
    if sc.mis:  # balance heuristic against the BRDF-sampled exit into the same cone direction
        q_j = sampling_pdf(wo_loc_j, w_in[:, 2])
        val = val / (1.0 + omega * _exit_density(q_j, jnp.maximum(w_air[:, 2], 0.0), w_in[:, 2], sc.n))
    score = event & (first | ~single)
    if opt.edges == "absorb":
        score = score & ~(hit & side)
    if sc.bidir:  # balance heuristic against the reverse tracer (source and detector swapped)
        val = val * _reverse_weight(sc, _source(sc, rid), hit, first, lg, wi_loc, wo_loc_j, w_in)
        lg_new = _update_log_ratio(sc, hit, first, lg, wi_loc, wo_loc, wo_pr)
    val = jnp.where(score & jnp.isfinite(val) & (val > 0), val, 0.0)
    if opt.shadow_roulette > 0:  # unbiased roulette on small contributions saves shadow rays
        small = val < opt.shadow_roulette
        val = jnp.where(small, jnp.where(u[_NU + 2 * m : _NU + 3 * m] * opt.shadow_roulette < val, opt.shadow_roulette, 0.0), val)
    new_sh_val = val.astype(dtype)
    new_sh_dir = w_in.astype(dtype)
    new_sh_lim = ((sc.h_b - origin[2]) / w_in[:, 2]).astype(dtype)

    # --- top of the basecoat: clearcoat transit, Fresnel split at the (facet of the) surface, histogram
    cz = jnp.where(top, dz, 1.0)
    shift_c = sc.h_c * d[:2] / cz
    if sc.wavy:  # the facet the ray meets, from the visible-normal density; the reflection stays in the coat
        d_up = jnp.where(top, d, jnp.array([0.0, 0.0, 1.0], dtype))
        mt = sample_visible_facet(d_up, sc.slope_sd, uf[0], uf[1])
        t, cos_t = refract(d_up, -mt, sc.n)
        Rint = fresnel_dielectric(cos_t, sc.n, 1.0)[2]
        ex_air = t / jnp.linalg.norm(t)
        d_ref = reflect(d_up, mt)
        d_ref = d_ref.at[2].set(-jnp.abs(d_ref[2]))  # a reflection still going up (grazing) is mirrored down
    else:
        Rint = fresnel_dielectric(cz, sc.n, 1.0)[2]
        txy = sc.n * d[:2]
        ex_air = jnp.concatenate([txy, jnp.sqrt(jnp.clip(1.0 - jnp.sum(txy * txy), 0.0, 1.0))[None]])
        d_ref = d * jnp.array([1.0, 1.0, -1.0], dtype)
    w_exit = jnp.where(top, w * (1.0 - Rint), 0.0)
    ex_inst = _rotz(ex_air, cph, -sph)
    inside = (jnp.sum(sc.det_air * ex_inst[None], -1) >= sc.det_cos_alpha) & (omega > 0)
    hist = jnp.where(inside & (w_exit > 0), jnp.pi * w_exit / (jnp.maximum(omega, 1e-30) * jnp.maximum(ex_inst[2], 1e-12)), 0.0)
    # the exit's share of the estimate: all of it after a delta reflection (the splat of the
    # deterministic direction into the aperture; NEE cannot see a delta), the balance-heuristic
    # share 1 − (NEE's) after a continuous one under MIS, none otherwise
    if sc.mis:
        pb = omega * _exit_density(q_last, ex_air[2], cz, sc.n)
        share = jnp.where(spec_last, 1.0, pb / (1.0 + pb))
    else:
        share = spec_last.astype(dtype)
    nee = jnp.where(~single | (nev <= 1), share * hist, 0.0)

    # --- new state and ledger
    new_w = jnp.where(event, w * factor, jnp.where(top, w * Rint, w))
    new_d = jnp.where(event, wo, jnp.where(top, d_ref, d))
    new_pos = jnp.where(hit, x_hit + sc.eps * nf, pos)
    new_pos = jnp.where(bottom, jnp.concatenate([x_bot[:2], sc.eps[None]]), new_pos)
    shift_down = sc.h_c * d_ref[:2] / jnp.where(top, -d_ref[2], 1.0)
    new_pos = jnp.where(top, jnp.concatenate([pos[:2] + t_slab * d[:2] + shift_c + shift_down, (sc.h_b - sc.eps)[None]]), new_pos)
    new_pos = jnp.where(moving, pos + (treach + sc.eps) * d, new_pos)
    new_pos = jnp.concatenate([jnp.mod(new_pos[:2], sc.tile), jnp.clip(new_pos[2:], 0.0, sc.h_b)])
    absorbed_pl = jnp.where(hit, w * (1.0 - factor), 0.0)
    absorbed_pr = jnp.where(bottom, w * (1.0 - factor), 0.0)
    # single scattering: a path ends after a non-delta first event (its NEE is scored), at its
    # second event (uncounted, cut before scattering) or at the internal reflection after the
    # first event
    second = event & (nev >= 1)
    # (under MIS the first event's ray goes on to its exit, which carries part of the estimate)
    early = jnp.zeros((), bool) if sc.mis else event & first & ~spec
    cut = single & alive & (second | (top & (nev >= 1)) | early)
    w_cut = jnp.where(cut, jnp.where(second, w, new_w), 0.0)
    absorbed_pl = jnp.where(cut & second, 0.0, absorbed_pl)
    absorbed_pr = jnp.where(cut & second, 0.0, absorbed_pr)
    new_w = jnp.where(cut, 0.0, new_w)
    alive2 = alive & ~cut
    rr = jnp.zeros((), dtype)
    if opt.roulette_weight > 0:
        low = alive2 & (event | top) & (new_w < opt.roulette_weight)
        survive = u[7] * opt.roulette_weight < new_w
        rr = jnp.where(low, jnp.where(survive, new_w - opt.roulette_weight, new_w), 0.0)
        new_w = jnp.where(low, jnp.where(survive, opt.roulette_weight, 0.0), new_w)
        alive2 = alive2 & ~(low & ~survive)
    alive2 = alive2 & (new_w > 0)
    nstep2 = nstep + alive.astype(nstep.dtype)
    capped = alive2 & (nstep2 >= opt.max_steps)
    caps = w_cut + jnp.where(capped, new_w, 0.0)
    alive2 = alive2 & ~capped
    z = jnp.zeros((), dtype)
    ledger = jnp.stack([z, w_exit, absorbed_pl, absorbed_pr, rr, caps])
    ledger = jnp.where(alive, ledger, 0.0)
    hist = jnp.where(alive, hist, 0.0)
    nee = jnp.where(alive, nee, 0.0)
    tally = jnp.concatenate([nee, hist, ledger, jnp.zeros(1, dtype)])
    keep_sh = alive & event
    new_ray = (new_pos.astype(dtype), new_d.astype(dtype), jnp.where(alive2, new_w, 0.0).astype(dtype), alive2, cph, sph,
               nstep2, nev + event.astype(nev.dtype), rid, jnp.where(event, spec, spec_last),
               jnp.where(event, q_ev, q_last).astype(dtype) if sc.mis else q_last,
               jnp.where(event, lg_new, lg).astype(dtype) if sc.bidir else lg, origin.astype(dtype), new_sh_dir,
               new_sh_lim, jnp.where(keep_sh, new_sh_val, 0.0))
    return new_ray, tally


def _shadow_leg(sc: _Scene, opt: TracerOptions) -> int:
    """Cells a shadow ray crosses per pass: `opt.shadow_leg_cells`, at most the scene's bound to the top."""
    return min(int(opt.shadow_leg_cells), sc.shadow_cells)


def _shadows(sc: _Scene, opt: TracerOptions, org, sh_dir, sh_lim, sh_val):
    """Trace the pending shadow rays of all lanes (compacted, in passes of a fixed buffer).

    Each pass walks every shadow ray in the buffer by at most `opt.shadow_leg_cells` cells; one not yet
    decided (no occluder so far, top not reached) resumes where it stopped in a later pass, so every
    shadow ray is decided, whatever the leg length. Returns the NEE increment (lanes, m): the pending
    values of the visible shadow rays.
    """
    B, m = sh_val.shape
    total = B * m
    S = max(1, min(total, int(round(opt.shadow_buffer * total))))
    dirs = sh_dir.reshape(-1, 3)
    # passes: ceil(total / S) per leg. A ray within the flat coat's critical angle crosses at most
    # shadow_cells cells (`_shadow_cell_bound`), one of tan θ ≤ _WAVY_MAX_TAN_IN at most
    # ⌈_WAVY_MAX_TAN_IN / tan θ_c⌉ times as many (3 for n = 1.5; 5 allowed). The first leg crosses `leg`
    # new cells, each later one ≥ leg − 1 (it may start in the cell where the last one stopped: the
    # resumption point lies on its boundary). A guard against a runaway loop only: a ray still pending
    # when it stops would count as occluded, which the bound rules out
    leg = _shadow_leg(sc, opt)
    cells = sc.shadow_cells * (jnp.ceil(_WAVY_MAX_TAN_IN * jnp.sqrt(jnp.maximum(sc.n**2 - 1.0, 1e-12))) + 1.0 if sc.wavy else 1.0)
    legs = 1.0 + jnp.ceil(jnp.maximum(cells - leg, 0.0) / max(leg - 1, 1))
    max_passes = jnp.asarray(legs * (-(-total // S)) + 1).astype(jnp.int32)

    def cond(c):
        return jnp.any(c[2]) & (c[0] < max_passes)

    def body(c):
        it, orgs, pending, lims, vis = c
        idx = jnp.nonzero(pending, size=S, fill_value=total)[0]
        ok = idx < total
        j = jnp.minimum(idx, total - 1)
        tb, _, _, reach, fin = jax.vmap(lambda a, b, c_: _traverse(sc, a, b, c_, True, leg))(orgs[j], dirs[j], lims[j])
        vis = vis.at[idx].max(ok & fin & (tb >= lims[j]), mode="drop")
        pending = pending.at[idx].set(~fin, mode="drop")  # unfinished: no occluder so far, resume at the reach
        orgs = orgs.at[idx].set(orgs[j] + reach[:, None] * dirs[j], mode="drop")
        lims = lims.at[idx].set(lims[j] - reach, mode="drop")
        return it + 1, orgs, pending, lims, vis

    init = (jnp.asarray(0, jnp.int32), jnp.repeat(org, m, axis=0), (sh_val > 0).reshape(-1), sh_lim.reshape(-1), jnp.zeros(total, bool))
    vis = jax.lax.while_loop(cond, body, init)[-1]
    return jnp.where(vis.reshape(B, m), sh_val, 0.0)


# ----------------------------------------------------------------------------------------------
