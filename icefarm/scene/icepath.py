"""An ice-aware path tracer for Mitsuba 3: caustics off, transmissive shadows through ice.

Glaze is a thin dielectric shell over the object, and the object's top lies inside it.
Mitsuba's ``path`` integrator cannot light anything through a dielectric from a delta
light (a shadow ray is blocked by any surface, and a sun cannot be hit by a refracted
ray), so glazed surfaces and icicle shadows get no sunlight and render dark and noisy.
Production renderers fix this with "transmissive shadows": ice is a full dielectric
only for paths that have seen nothing but specular events since the camera (so the
camera still sees refraction and reflection); after the first non-delta bounce every
ice surface is a straight pass-through weighted by its Fresnel transmittance, for the
path itself and for next-event shadow rays alike. This drops caustics, which is what the
eye expects from clear ice anyway. A shadow ray is cast only where the light it could bring
is not 0 (the BSDF's value toward the emitter sample), which spares most of them at smooth
ice and at surfaces lit from behind.

What fills the ice (the ``homogeneous`` medium of ``scene.xml``: absorption and, for ice
grown from impure water, scattering) is handled as ``volpath`` does, with the same
shortcut at the ice's surface and a cheaper walk. Absorption is Beer-Lambert,
``exp(-sigma_a d)`` over the distance ``d`` a path travels inside, applied exactly rather
than sampled (no noise, however faint the tint). Scattering (grey, isotropic: the phase
function Mitsuba gives a ``homogeneous`` medium by default) is sampled: inside the ice a
path meets a scattering point at a distance drawn from ``sigma_s exp(-sigma_s s)``,
where it takes next-event estimation and a new direction, like a surface vertex; as that
is not a delta event, the ice surfaces it meets afterwards are pass-throughs, so light
scattered in an icicle's cloudy core leaves it without being trapped by total internal
reflection. Cheaply: a path scatters at most once in the ice (after that its light is
taken to go on forward, losing only what the ice absorbs), and after that point it gets
`AFTER_SCATTER` more vertices (the light that reaches the cloudy core from the object and
the ground after one bounce, not after several). Shadow rays are attenuated by
``exp(-(sigma_a + sigma_s) d)``. A segment is inside the ice when the last ice surface it
crossed was entered (the ray against the surface's outward normal); a shadow ray needs
no such state: every ice surface it leaves ends a stretch inside.

The integrator is a Python `mitsuba.SamplingIntegrator`, so it only makes sense on JIT
variants (``llvm_ad_rgb``, ``cuda_ad_rgb``), where Mitsuba traces `sample` once into a
kernel; on scalar variants it would run in Python per sample, and
`icefarm.scene.integrator.ice_integrator` returns None there. Mitsuba's classes depend on
the active variant, so the class is built per variant by
`icefarm.scene.integrator.integrator_class` from the methods here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .config import IceLook

MAX_CROSSINGS = 16  # pass-throughs per path segment (and per shadow ray) before absorbing
RR_DEPTH = 5  # Mitsuba's path default: Russian roulette from this depth on
ISOTROPIC = 1.0 / (4.0 * math.pi)  # phase function value of isotropic scattering
AFTER_SCATTER = 2  # real vertices a path may have after it scattered inside the ice
# The denoiser's feature buffers, after RGB: albedo and normal where the path first meets
# something that is not a mirror or a refraction (through the ice, what it shows).
FEATURE_CHANNELS = ("albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y", "normal.Z")


def rgb_coefficients(value, name: str) -> tuple[float, float, float]:
    """Three finite non-negative numbers (per meter) from a number, a sequence or a colour."""
    try:
        values = [float(value)] * 3
    except TypeError:
        values = [float(v) for v in value]
    if len(values) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in values):
        raise ValueError(f"{name} must be three finite numbers >= 0 (per meter), got {value!r}")
    return tuple(values)


def dr_opaque_spectrum(values: Sequence[float]):
    """``mi.Spectrum`` of ``values`` as a kernel input, not a constant compiled into it."""
    import drjit as dr
    import mitsuba as mi

    return mi.Spectrum(*(dr.opaque(mi.Float, float(v)) for v in values))


def _mis_weight(pdf_a, pdf_b):
    """Power heuristic, 0 where it is not finite (as in Mitsuba's ``ad/integrators/common.py``)."""
    import drjit as dr

    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.select(dr.isfinite(w), w, 0.0)


class IcePathMethods:
    """Methods of the variant's ``IcePathIntegrator``.

    Mitsuba's base classes exist only once a variant is set, and nanobind classes take a
    single base, so the methods live here and `icefarm.scene.integrator.integrator_class`
    copies them into a subclass of that variant's ``mitsuba.SamplingIntegrator``.

    Properties: ``max_depth`` (int, -1 unbounded; default 12), ``rr_depth`` (5),
    ``ior`` (1.31), ``tint`` (rgb, (1, 1, 1)), ``max_crossings`` (16), ``sigma_a`` and
    ``sigma_s`` (rgb, absorption and scattering of the ice per scene unit; default 0),
    ``features`` (bool, default False: also write the denoiser's albedo and normal,
    `FEATURE_CHANNELS`) and the base class's ``hide_emitters``.
    """

    def __init__(self, props):
        import mitsuba as mi

        mi.SamplingIntegrator.__init__(self, props)
        max_depth = int(props.get("max_depth", 12))
        if max_depth < -1 or max_depth == 0:
            raise ValueError(f"max_depth must be -1 (unbounded) or >= 1, got {max_depth}")
        self.max_depth = 2**32 - 1 if max_depth == -1 else max_depth  # compared as UInt32
        self.rr_depth = int(props.get("rr_depth", RR_DEPTH))
        self.ior = float(props.get("ior", IceLook.ior))
        self.tint = tuple(float(t) for t in props.get("tint", IceLook.tint))
        self.max_crossings = int(props.get("max_crossings", MAX_CROSSINGS))
        if not self.ior >= 1.0:
            raise ValueError(f"ior must be >= 1, got {self.ior}")
        if len(self.tint) != 3 or not all(0.0 <= t <= 1.0 for t in self.tint):
            raise ValueError(f"tint must be three numbers in [0, 1], got {self.tint}")
        if self.rr_depth < 1 or self.max_crossings < 0:
            raise ValueError("rr_depth must be >= 1 and max_crossings >= 0")
        self.features = bool(props.get("features", False))
        self.sigma_a = rgb_coefficients(props.get("sigma_a", 0.0), "sigma_a")
        self.sigma_s = rgb_coefficients(props.get("sigma_s", 0.0), "sigma_s")
        # Kernel inputs rather than constants: a sweep over impurity reuses one kernel.
        self._sigma_t = dr_opaque_spectrum([a + s for a, s in zip(self.sigma_a, self.sigma_s)])
        self._sigma_a = dr_opaque_spectrum(self.sigma_a)
        self._sigma_s = dr_opaque_spectrum(self.sigma_s)

    @property
    def has_medium(self) -> bool:
        """Whether the ice absorbs or scatters (otherwise no segment is attenuated)."""
        return max(self.sigma_a) + max(self.sigma_s) > 0.0

    @property
    def has_scattering(self) -> bool:
        return max(self.sigma_s) > 0.0

    def aov_names(self):
        return list(FEATURE_CHANNELS) if self.features else []

    def to_string(self):
        return (f"IcePathIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}, "
                f"ior={self.ior:g}, tint={self.tint}, max_crossings={self.max_crossings}, "
                f"sigma_a={self.sigma_a}, sigma_s={self.sigma_s}]")

    def _crossing(self, d, n):
        """Transmittance of one straight ice crossing: ``(1 - F(|cos|, ior)) * tint``.

        Fresnel is taken as if entering from air on both faces of a shell: a straight
        ray leaves at the angle it entered, and this keeps total internal reflection,
        which a pass-through cannot model, out of it.
        """
        import drjit as dr
        import mitsuba as mi

        cos = dr.abs(dr.dot(d, n))
        f = mi.fresnel(cos, mi.Float(self.ior))[0]
        return mi.Spectrum(self.tint) * (1.0 - f)

    def _is_ice(self, si):
        """Lanes whose surface transmits: the ice (dielectric, roughdielectric)."""
        import mitsuba as mi

        return si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Transmission)

    def _shadow(self, scene, it, target, active):
        """Transmittance from ``it`` to point ``target``: through ice, 0 past anything else.

        Parameters
        ----------
        scene : mi.Scene
        it : mi.SurfaceInteraction3f or mi.Interaction3f
            Where the shadow ray starts (on a surface, or a point inside the ice).
        target : mi.Point3f
            The emitter sample's position (``ds.p``; a far point for sun and sky).
        active : mi.Bool

        Returns
        -------
        mi.Spectrum
            Product of the crossings' transmittances and, where the ice absorbs or
            scatters, of ``exp(-sigma_t d)`` over each stretch ``d`` inside it (ended
            by an ice surface the ray leaves); 0 where blocked.
        """
        import drjit as dr
        import mitsuba as mi

        ray = it.spawn_ray_to(target)
        trans = mi.Spectrum(1.0)
        crossings = mi.UInt32(0)
        active = mi.Bool(active)
        while dr.hint(active, label="icepath shadow"):
            # Position and geometric normal suffice: no texture lookups on shadow rays.
            hit = scene.ray_intersect(ray, mi.RayFlags.Minimal, False, active)
            ice = active & self._is_ice(hit)
            blocked = active & hit.is_valid() & ~ice
            crossings[ice] += 1
            trans[ice] *= self._crossing(ray.d, hit.n)
            if dr.hint(self.has_medium, mode="scalar"):
                # spawn_ray_to leaves d unnormalised (t runs to 1 at the target)
                leaving = ice & (dr.dot(ray.d, hit.n) > 0.0)
                trans[leaving] *= dr.exp(-self._sigma_t * (hit.t * dr.norm(ray.d)))
            blocked |= ice & (crossings > self.max_crossings)
            trans[blocked] = 0.0
            active = ice & ~blocked
            ray = hit.spawn_ray_to(target)
        return trans

    def _free_flight(self, sampler, length, active):
        """Where a path inside the ice scatters on a stretch of ``length``, and its weight.

        The distance is drawn from ``m exp(-m s)`` with ``m`` the mean scattering
        coefficient; a path that gets past ``length`` reaches the surface. The weight
        holds the absorption over the distance travelled and, for a scattering
        coefficient that is not grey, the ratio to its mean (1 for icefarm's media).

        Returns
        -------
        scatters : mi.Bool
            Lanes that scatter before the surface.
        distance : mi.Float
            Distance travelled: to the scattering point, or ``length``.
        weight : mi.Spectrum
        """
        import drjit as dr

        mean_s = dr.mean(self._sigma_s)
        u = sampler.next_1d(active)
        s = -dr.log(1.0 - u) / mean_s
        scatters = active & (s < length)
        distance = dr.select(scatters, s, length)
        weight = dr.exp(-self._sigma_a * distance) * dr.exp((mean_s - self._sigma_s) * distance)
        weight[scatters] *= self._sigma_s / mean_s
        return scatters, distance, weight

    def sample(self, scene, sampler, ray_, medium=None, active_=True):
        """Radiance along camera rays ``ray_``: (spectrum, valid mask, AOVs: the denoiser's
        features with ``features`` set, else none).

        One symbolic loop over the path's segments, in the phases its ``# ----`` comments
        name. It is long on purpose, as Mitsuba's own integrators are: each phase reads and
        masks a dozen of the loop's variables, which helpers would have to pass in and out.
        """
        import drjit as dr
        import mitsuba as mi

        # ---- the path's state, carried through the loop
        bsdf_ctx = mi.BSDFContext()
        ray = mi.Ray3f(ray_)
        active = mi.Bool(active_)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)  # path throughput
        depth = mi.UInt32(0)  # real (scattering) vertices so far
        crossings = mi.UInt32(0)  # pass-throughs since the last real vertex
        specular = mi.Bool(True)  # only delta events since the camera: ice is a dielectric
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
        # The last real vertex: NEE ran there, so MIS of an emitter hit refers to it.
        prev_si = dr.zeros(mi.SurfaceInteraction3f)
        prev_pdf = mi.Float(1.0)
        prev_delta = mi.Bool(True)
        inside = mi.Bool(False)  # the segment being traced runs inside the ice
        scattered = mi.Bool(False)  # the path scattered inside the ice already
        last = mi.UInt32(self.max_depth)  # real vertices allowed (fewer once it scattered)
        albedo = mi.Spectrum(0.0)  # denoiser features, taken once per path (`FEATURE_CHANNELS`)
        normal = mi.Vector3f(0.0)
        featured = mi.Bool(not self.features)

        while dr.hint(active, label="icepath"):
            si = scene.ray_intersect(ray, active)
            ice = self._is_ice(si)

            # ---- the medium inside the ice along the segment just traced (ray.d is unit):
            # absorption, and for cloudy ice a scattering point before the surface
            scatter = mi.Bool(False)
            scatter_p = mi.Point3f(0.0)
            if dr.hint(self.has_medium, mode="scalar"):
                seg = active & inside & si.is_valid()  # a miss from inside: a leak, no medium
                length = dr.select(seg, si.t, 0.0)
                if dr.hint(self.has_scattering, mode="scalar"):
                    # One scattering event per path; after it the light is taken to go on
                    # forward through the cloudy ice, losing only what it absorbs.
                    flight = seg & ~scattered
                    scatter, distance, weight = self._free_flight(sampler, length, flight)
                    beta[flight] *= weight
                    beta[seg & scattered] *= dr.exp(-self._sigma_a * length)
                    scatter_p = ray(distance)
                    scattered |= scatter
                    last[scatter] = dr.minimum(last, depth + 1 + AFTER_SCATTER)
                else:
                    beta[seg] *= dr.exp(-self._sigma_a * length)

            # ---- what the path meets: a pass-through (ice seen past a diffuse or glossy
            # bounce) or a real vertex (any other surface, the sky, the ice up to that bounce)
            surface = active & ~scatter
            through = surface & ~specular & ice
            real = surface & ~through
            valid_ray |= (real & (depth == 0) & si.is_valid()) | scatter
            bsdf = si.bsdf(ray)

            # ---- denoiser features
            if dr.hint(self.features, mode="scalar"):
                # the first diffuse or glossy vertex seen through any mirror or refraction
                # chain, weighted by what that chain lets through; the sky where it escapes.
                # Frosted ice (a rough surface, the milky bands) is seen through too: the
                # denoiser keeps what lies behind it sharp.
                hit = real & si.is_valid() & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & ~ice
                sky = real & ~si.is_valid()
                take = ~featured & (hit | sky | scatter)
                seen = dr.select(hit, bsdf.eval_diffuse_reflectance(si, hit),
                                 dr.select(sky, scene.environment().eval(si, sky) if scene.environment()
                                           is not None else mi.Spectrum(0.0), 1.0))
                albedo[take] = dr.clip(beta * seen, 0.0, 1.0)
                normal[take] = dr.select(hit, si.sh_frame.n, mi.Vector3f(0.0))
                featured |= take

            # ---- pass-through: same direction, Fresnel transmittance, not a bounce
            crossings[through] += 1
            beta[through] *= self._crossing(ray.d, si.n)
            inside[through] = dr.dot(ray.d, si.n) < 0.0  # entering against the outward normal
            through_next = through & (crossings <= self.max_crossings)

            # ---- real vertex: emission reached by BSDF sampling, MIS against NEE at prev_si
            ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
            em_pdf = scene.pdf_emitter_direction(prev_si, ds, real & ~prev_delta)
            emit = real
            if dr.hint(self.hide_emitters, mode="scalar"):
                emit &= ~((depth == 0) & ~si.is_valid())
            Le = beta * _mis_weight(prev_pdf, em_pdf) * ds.emitter.eval(si, emit)
            L += dr.select(emit, Le, 0.0)

            real_next = real & si.is_valid() & (depth + 1 < last)
            scatter_next = scatter & (depth + 1 < last)

            # ---- next-event estimation with shadow rays that pass through ice, from si
            # or from the scattering point (one emitter sample, one shadow ray)
            active_em = real_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ref = dr.zeros(mi.Interaction3f)
            ref.p = dr.select(scatter, scatter_p, si.p)
            ref.n = dr.select(scatter, mi.Vector3f(0.0), si.n)  # no offset inside the ice
            ref.time, ref.wavelengths = ray.time, ray.wavelengths
            ds, em_weight = scene.sample_emitter_direction(ref, sampler.next_2d(), False,
                                                           active_em | scatter_next)
            active_em &= ds.pdf != 0.0
            active_ph = scatter_next & (ds.pdf != 0.0)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(bsdf_ctx, si, si.to_local(ds.d), active_em)
            f_pdf = dr.select(active_ph, ISOTROPIC, bsdf_pdf)
            mis_em = dr.select(ds.delta, 1.0, _mis_weight(ds.pdf, f_pdf))
            f_val = dr.select(active_ph, mi.Spectrum(ISOTROPIC), bsdf_val)
            unshadowed = beta * mis_em * f_val * em_weight
            # A shadow ray only where it could bring light, not where the BSDF's value is 0:
            # light from behind a surface, or ice where it is smooth (its delta lobes NEE
            # cannot reach): the car's two lookdev views render in 9.8 s instead of 12.9 s.
            # A BSDF's value can be NaN at a degenerate configuration (roughdielectric: once in
            # the 33 M samples of the 0.3 m bunny's two 480 x 360 views at 96 spp): one such
            # sample would poison the pixels its filter reaches. A set of measure zero: drop it.
            lit = (active_em | active_ph) & dr.all(dr.isfinite(unshadowed)) & (dr.max(unshadowed) > 0.0)
            L += dr.select(lit, unshadowed * self._shadow(scene, ref, ds.p, lit), 0.0)

            # ---- BSDF sampling
            bs, bsdf_weight = bsdf.sample(bsdf_ctx, si, sampler.next_1d(), sampler.next_2d(),
                                          real_next)
            delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            # a NaN weight, like a NaN value above, ends the path rather than poisoning it
            bsdf_weight = dr.select(dr.all(dr.isfinite(bsdf_weight)), bsdf_weight, 0.0)
            # Dielectrics scale radiance by 1/eta^2 on entering (solid angle compression)
            # and back on leaving; a path that ends inside ice (a glazed surface, whose
            # light then passes straight out) never leaves, which would darken everything
            # under glaze by 1/1.31^2. Ice here does not concentrate light: undo it.
            beta[real] *= bsdf_weight * dr.square(bs.eta)
            wo = si.to_world(bs.wo)
            inside[real & ice] = dr.dot(wo, si.n) < 0.0  # refracted in (or reflected inside)
            prev_si = dr.select(real, si, prev_si)
            prev_pdf[real] = bs.pdf
            prev_delta[real] = delta
            specular &= ~real | delta  # the first non-delta bounce turns ice into pass-through

            # ---- phase function sampling at a scattering point (isotropic: weight 1)
            if dr.hint(self.has_scattering, mode="scalar"):
                wo = dr.select(scatter, mi.warp.square_to_uniform_sphere(sampler.next_2d(scatter)), wo)
                at = dr.zeros(mi.SurfaceInteraction3f)
                at.p, at.t, at.time, at.wavelengths = scatter_p, 0.0, ray.time, ray.wavelengths
                prev_si = dr.select(scatter, at, prev_si)
                prev_pdf[scatter] = ISOTROPIC
                prev_delta[scatter] = False
                specular &= ~scatter
            vertex = real | scatter
            vertex_next = real_next | scatter_next
            crossings[vertex] = 0

            # ---- Russian roulette, as in Mitsuba's path (whose eta^2 factor here only
            # cancels the radiance scaling undone above)
            beta_max = dr.max(beta)
            vertex_next &= beta_max != 0.0
            rr_prob = dr.minimum(beta_max, 0.95)
            rr_active = vertex_next & (depth >= self.rr_depth)
            beta[rr_active] *= dr.rcp(rr_prob)
            vertex_next &= ~rr_active | (sampler.next_1d() < rr_prob)
            depth[(real & si.is_valid()) | scatter] += 1

            # ---- the next segment: straight on through the ice, along the sampled direction,
            # or from the scattering point
            ray = dr.select(through, si.spawn_ray(ray.d), si.spawn_ray(wo))
            if dr.hint(self.has_scattering, mode="scalar"):
                ray = dr.select(scatter, mi.Ray3f(scatter_p, wo, ray.time, ray.wavelengths), ray)
            active = (through_next & (beta_max != 0.0)) | vertex_next

        aovs = [albedo[0], albedo[1], albedo[2], normal[0], normal[1], normal[2]] if self.features else []
        return L, valid_ray, aovs
