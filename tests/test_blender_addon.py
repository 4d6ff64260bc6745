"""The Blender add-on (the package icefarm/dcc/blender_addon/) in the real Blender 5.0 (``bpy``
in .venv-blender), each test a Blender process running icefarm as the add-on does.

What runs for real: installing and enabling the add-on, the export to GLB, the ``icefarm
run`` command line it builds, the job in its own process, reading its progress lines, the
import of ``ice.ply`` as glass parented in place, the operator called from a script
(``EXEC_DEFAULT``), its error reports, and the modal operator's ``modal`` step and Cancel
operator, and the panel's and the preferences' ``draw`` (on a layout that records what it
is asked to draw). What does not: Blender's event loop (there is none in background mode,
where ``INVOKE_DEFAULT`` runs ``execute``), so the modal operator's ``invoke`` (its window
timer and modal handler) never runs and ``modal`` is driven by hand with TIMER events on a
stand-in for the operator; nothing is drawn on a screen.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PYTHON = ROOT / ".venv-blender" / "bin" / "python"
ADDON = ROOT / "icefarm" / "dcc" / "blender_addon"  # the package's folder
ICEFARM = Path(sys.executable).parent / "icefarm"
BUNNY = ROOT.parent / "shared" / "meshes" / "stanford-bunny.obj"
# Jobs in seconds: few icicles, a coarse ice lattice
FAST = "storm.max_icicles=8 surface.voxel_size=0.003"

pytestmark = [
    pytest.mark.slow,  # each test starts Blender, which starts icefarm jobs
    pytest.mark.skipif(not BLENDER_PYTHON.is_file(), reason="no .venv-blender with bpy (.ci/setup.sh makes it)"),
]

# Run in Blender: helpers for every mode, then the mode named in the arguments.
BLENDER = textwrap.dedent('''
    import importlib.util, json, math, os, sys, tempfile, time
    from types import SimpleNamespace
    import bpy, numpy as np
    from mathutils import Matrix, Vector

    ARGS = json.loads(sys.argv[1])
    OUT = {}

    def load_addon():
        """The add-on package from its folder, registered, as Blender's add-on folder would load it."""
        spec = importlib.util.spec_from_file_location("blender_addon", os.path.join(ARGS["addon"], "__init__.py"),
                                                      submodule_search_locations=[ARGS["addon"]])
        addon = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(addon)
        addon.register()
        return addon

    def world(obj):
        m = np.array(obj.matrix_world)
        co = np.array([v.co for v in obj.data.vertices])
        return co @ m[:3, :3].T + m[:3, 3]

    def ice_record(ice):
        bsdf = next(n for n in ice.active_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        local = np.array([v.co for v in ice.data.vertices])  # the parent's frame (identity parent inverse)
        return {"name": ice.name, "parent": ice.parent.name if ice.parent else None, "faces": len(ice.data.polygons),
                "transmission": bsdf.inputs["Transmission Weight"].default_value,
                "ior": bsdf.inputs["IOR"].default_value, "material": ice.active_material.name,
                "collections": [c.name for c in ice.users_collection],
                "local_lo": local.min(0).tolist(), "local_hi": local.max(0).tolist(),
                "world_lo": world(ice).min(0).tolist(), "world_hi": world(ice).max(0).tolist(),
                "parent_inverse_identity": ice.matrix_parent_inverse == Matrix.Identity(4)}

    def contents():
        temp = sorted(name for name in os.listdir(tempfile.gettempdir()) if name.startswith("icefarm"))
        return {"objects": sorted(o.name for o in bpy.data.objects), "meshes": len(bpy.data.meshes),
                "materials": len(bpy.data.materials), "temp": temp}

    def select(*objects):
        bpy.ops.object.select_all(action="DESELECT")
        for obj in objects:
            obj.select_set(True)
        bpy.context.view_layer.objects.active = objects[0] if objects else None

    def grow_reports():
        """bpy.ops.icefarm.grow() from a script: its ERROR lines (bpy.ops raises them)."""
        try:
            result = bpy.ops.icefarm.grow()
        except RuntimeError as exc:
            return [line for line in str(exc).splitlines() if line.strip()]
        return list(result)

    class Operator:
        """A stand-in for the running modal operator: ``modal`` and ``_stop`` as the class
        has them, with a timer and the reports collected."""
        def __init__(self, addon):
            cls = addon.ui.ICEFARM_OT_grow
            self.modal = lambda context, event: cls.modal(self, context, event)
            self._stop = lambda context, grow: cls._stop(self, context, grow)
            self._finish = lambda grow: cls._finish(self, grow)
            self._timer = bpy.context.window_manager.event_timer_add(0.1, window=None)
            self.reports = []
        def report(self, kind, message):
            self.reports.append([sorted(kind)[0], message])

    def start_modal(addon, objects):
        """What invoke does, less its modal handler: the Grow, the panel's state."""
        select(*objects)
        grow = addon.ui.ICEFARM_OT_grow._start(None, bpy.context)  # icefarm from ICEFARM, the panel's settings
        addon.ui._ACTIVE.append(grow)
        state = bpy.context.window_manager.icefarm
        state.running, state.cancel = True, False
        return grow, Operator(addon)

    def install(path, module):
        """The add-on installed from ``path`` (its zip) and enabled, as Install from Disk does."""
        bpy.ops.preferences.addon_install(filepath=path, overwrite=True)
        bpy.ops.preferences.addon_enable(module=module)
        OUT["installed_in"] = sys.modules[module].__file__
        OUT["submodules"] = {name: sys.modules[name].__file__ for name in sys.modules if name.startswith(module + ".")}
        return sys.modules[module]

    def mode_install_and_grow():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        install(ARGS["zip"], "icefarm_blender")
        bpy.context.preferences.addons["icefarm_blender"].preferences.executable = ARGS["icefarm"]
        scene = bpy.context.scene
        scene.unit_settings.scale_length = 0.01  # a scene in centimetres: 1 unit is 1 cm
        bpy.ops.mesh.primitive_cube_add(size=2.0, location=(100.0, 200.0, 300.0), rotation=(0, 0, math.radians(30)))
        cube = bpy.context.active_object
        cube.scale = (50.0, 50.0, 50.0)  # 100 units: 1 m
        select(cube)
        scene.icefarm.settings = ARGS["fast"]
        before = contents()
        start = time.perf_counter()
        OUT["result"] = grow_reports()
        OUT["seconds"] = time.perf_counter() - start
        OUT["ice"] = ice_record(bpy.data.objects["Cube ice"])
        OUT["before"], OUT["after"] = before, contents()
        OUT["state"] = {"running": bpy.context.window_manager.icefarm.running}

    def mode_bunny_modal_and_cancel():
        addon = load_addon()
        path = os.environ["PATH"]
        os.environ["PATH"] = ""  # no ICEFARM, no icefarm on the PATH: the .venv beside the repository
        OUT["found_without_path"] = addon.command.find_executable()
        os.environ["PATH"] = path
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        bpy.ops.wm.obj_import(filepath=ARGS["bunny"])  # Y up to Blender's Z up
        bunny = bpy.context.selected_objects[0]
        bunny.name = "bunny"
        bpy.context.view_layer.update()
        bunny.scale = bunny.scale * (0.3 / np.ptp(world(bunny)[:, 2]))  # 0.3 m tall
        bunny.location = (0.5, -0.2, 0.1)
        bpy.context.view_layer.update()
        select(bunny)
        scene.icefarm.settings, scene.icefarm.seed = ARGS["fast"], 5
        os.environ["ICEFARM"] = ARGS["icefarm"]
        options = addon.command.JobOptions(intensity="severe", kind="meltwater", seed=1, placement="hanging",
                                   render="lookdev")
        OUT["render_command"] = addon.command.job_command("icefarm", "in.glb", "out", 2.5, options)
        grow, op = start_modal(addon, [bunny])
        job = grow.jobs[0]
        OUT["command"], OUT["size_m"] = job.command, job.size_m
        OUT["exported"] = job.mesh.is_file()
        timer = SimpleNamespace(type="TIMER")
        seen, result = [], {"PASS_THROUGH"}
        for _ in range(1200):
            result = op.modal(bpy.context, timer)
            state = bpy.context.window_manager.icefarm
            seen.append([state.progress, state.status])
            if result != {"PASS_THROUGH"}:
                break
            if len(seen) == 1:  # the artist moves the bunny while its ice grows
                bunny.location.x += 1.0
            time.sleep(0.05)
        bpy.context.view_layer.update()
        OUT["modal_result"], OUT["seen"], OUT["reports"] = sorted(result), seen, op.reports
        OUT["ice"] = ice_record(bpy.data.objects["bunny ice"])
        OUT["bunny_lo"], OUT["bunny_hi"] = world(bunny).min(0).tolist(), world(bunny).max(0).tolist()
        OUT["summary"] = job.process.progress.summary

        # Cancel: a slower job (the 1 m cube at the default lattice), stopped in its surface step
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(3.0, 0.0, 0.0))
        cube = bpy.context.active_object
        select(cube)
        scene.icefarm.settings = "storm.max_icicles=8"
        before = contents()
        grow, op = start_modal(addon, [cube])
        for _ in range(600):
            assert op.modal(bpy.context, timer) == {"PASS_THROUGH"}
            if grow.jobs[0].process.progress.step == "surface":
                break
            time.sleep(0.05)
        process = grow.jobs[0].process
        OUT["cancelled_in"] = process.progress.step
        OUT["running_before_cancel"] = process.process.poll() is None
        bpy.ops.icefarm.cancel()  # the panel's button
        start = time.perf_counter()
        OUT["cancel_result"] = sorted(op.modal(bpy.context, timer))
        OUT["cancel_seconds"] = time.perf_counter() - start
        OUT["cancel_reports"] = op.reports
        try:
            os.killpg(process.pid, 0)
            OUT["group_left"] = True
        except ProcessLookupError:
            OUT["group_left"] = False
        OUT["returncode"] = process.process.returncode
        OUT["before"], OUT["after"] = before, contents()
        OUT["active"] = len(addon.ui._ACTIVE)

    class Layout:
        """Records what a panel draws; ``prop`` checks its property exists."""
        def __init__(self, drawn):
            self.drawn = drawn
        def column(self):
            return self
        def prop(self, data, name):
            assert name in data.bl_rna.properties, name
            self.drawn.append("prop " + name)
        def label(self, text="", icon="NONE"):
            self.drawn.append("label " + text)
        def operator(self, idname, icon="NONE"):
            getattr(bpy.ops.icefarm, idname.split(".")[1]).get_rna_type()  # registered
            self.drawn.append("operator " + idname)
        def progress(self, factor=0.0, type="BAR", text=""):
            self.drawn.append(f"progress {factor:.2f} {text}")

    def draw(addon, cls, owner=None):
        drawn = []
        own = {"executable": owner, "bl_rna": cls.bl_rna} if owner is not None else {}  # the preferences' own
        cls.draw(SimpleNamespace(layout=Layout(drawn), **own), bpy.context)
        return drawn

    def mode_bad_input():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        addon = install(ARGS["zip"], "icefarm_blender")
        scene = bpy.context.scene
        bpy.ops.mesh.primitive_cube_add(size=1.0)
        cube = bpy.context.active_object
        OUT["panel"] = draw(addon, addon.ui.ICEFARM_PT_grow)
        bpy.context.window_manager.icefarm.running, bpy.context.window_manager.icefarm.progress = True, 0.25
        bpy.context.window_manager.icefarm.status = "Cube (1/1): surface"
        OUT["panel_running"] = draw(addon, addon.ui.ICEFARM_PT_grow)
        bpy.context.window_manager.icefarm.running = False
        os.environ["ICEFARM"] = ARGS["icefarm"]
        OUT["preferences"] = draw(addon, addon.ui.IcefarmPreferences, owner="")
        bpy.ops.object.camera_add()
        camera = bpy.context.active_object
        points = bpy.data.meshes.new("points")
        points.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [])
        loose = bpy.data.objects.new("points", points)
        scene.collection.objects.link(loose)
        cases = {"nothing selected": ([], None), "a camera": ([camera], None), "no faces": ([loose], None),
                 "a failing icefarm": ([cube], ARGS["failing"]), "no such icefarm": ([cube], ARGS["missing"]),
                 "an unknown setting": ([cube], ARGS["icefarm"])}
        OUT["cases"] = {}
        for name, (objects, executable) in cases.items():
            select(*objects)
            os.environ["ICEFARM"] = executable or ARGS["icefarm"]
            scene.icefarm.settings = "storm.nonsense=1" if name == "an unknown setting" else ARGS["fast"]
            before = contents()
            reports = grow_reports()
            OUT["cases"][name] = {"reports": reports, "unchanged": contents() == before}

    globals()["mode_" + ARGS["mode"]]()
    print("RESULT " + json.dumps(OUT))
''')


def run_blender(tmp_path, mode, timeout=120, **args):
    """Run ``mode`` of `BLENDER` in a fresh Blender with its own temporary folder and user
    resources under ``tmp_path``; returns its RESULT and its stdout."""
    temp = tmp_path / "tmp"
    temp.mkdir(exist_ok=True)
    env = {**os.environ, "TMPDIR": str(temp), "BLENDER_USER_RESOURCES": str(tmp_path / "blender-user")}
    env.pop("ICEFARM", None)
    args = {"mode": mode, "addon": str(ADDON), "icefarm": str(ICEFARM), "fast": FAST, **args}
    done = subprocess.run([str(BLENDER_PYTHON), "-c", BLENDER, json.dumps(args)], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[len("RESULT "):]), done.stdout


def test_the_addon_installs_and_grows_glass_ice_on_a_cube_in_a_centimetre_scene(tmp_path):
    """Installed from its zip (`write_blender_addon`) and enabled, ``bpy.ops.icefarm.grow()``
    on a 1 m cube (100 units at 1 cm each, rotated 30 degrees, away from the origin) brings
    back glass ice parented to it, around it, thickest on top, none under it (it rests on
    the ground)."""
    from icefarm.dcc.addon_zip import write_blender_addon

    addon_zip = write_blender_addon(tmp_path / "dist" / "icefarm_blender.zip")
    out, stdout = run_blender(tmp_path, "install_and_grow", zip=str(addon_zip))
    assert out["result"] == ["FINISHED"]
    installed = tmp_path / "blender-user" / "scripts" / "addons" / "icefarm_blender"
    assert out["installed_in"] == str(installed / "__init__.py")
    assert out["submodules"] == {f"icefarm_blender.{name}": str(installed / f"{name}.py")
                                 for name in ("command", "grow", "process", "scene", "ui")}
    ice = out["ice"]
    assert ice["name"] == "Cube ice" and ice["parent"] == "Cube" and ice["parent_inverse_identity"]
    assert ice["transmission"] == 1.0 and ice["ior"] == pytest.approx(1.31) and ice["material"] == "icefarm ice"
    assert ice["collections"] == ["Collection"] or ice["collections"] == ["Scene Collection"]
    assert ice["faces"] > 1000
    # In the cube's own frame (half-size 1 = 0.5 m) the ice covers its four sides and its
    # top, at most 5 cm (0.1) off them: a wrong unit, axis or rotation would put it metres away
    lo, hi = ice["local_lo"], ice["local_hi"]
    for axis in (0, 1):
        assert -1.1 < lo[axis] < -1.0 and 1.0 < hi[axis] < 1.1, (lo, hi)
    assert 1.01 < hi[2] < 1.1, "the glaze on top (a moderate storm: about 1.6 cm)"
    assert lo[2] > -1.02, "no ice under a cube resting on the ground"
    assert out["after"]["objects"] == ["Cube", "Cube ice"] and out["after"]["materials"] == 1
    assert out["after"]["temp"] == [], "the temporary export and job folder are removed"
    assert not out["state"]["running"]
    assert "Info: Cube: ice:" in stdout  # the job's summary in the report line
    print(f"grow from bpy.ops: {out['seconds']:.1f} s")


@pytest.mark.skipif(not BUNNY.is_file(), reason=f"{BUNNY} not available")
def test_the_modal_operator_grows_icicles_on_a_bunny_and_cancel_stops_icefarm(tmp_path):
    """The modal operator's step, driven by TIMER events, runs the job with the settings the
    panel holds (icefarm found through ICEFARM), shows its progress, and brings the icicles
    back onto the bunny, moved meanwhile; its Cancel button stops a running job, process and children, and
    nothing of it comes back. The add-on is the package loaded from the repository's folder
    here: with no ICEFARM and nothing on the PATH it finds the repository's .venv."""
    wrapper = tmp_path / "icefarm-from-env"  # named by ICEFARM: the command runs it, not the venv's
    wrapper.write_text(f'#!/bin/sh\nexec "{ICEFARM}" "$@"\n')
    wrapper.chmod(0o755)
    out, _ = run_blender(tmp_path, "bunny_modal_and_cancel", timeout=150, bunny=str(BUNNY), icefarm=str(wrapper))
    venv = ROOT / ".venv" / "bin" / "icefarm"
    if venv.is_file():  # the add-on loaded from the repository finds the .venv beside it
        assert out["found_without_path"] == str(venv)
    command = out["command"]
    assert command[:2] == [str(wrapper), "run"] and command[command.index("-o") + 1].startswith(str(tmp_path))
    assert float(command[command.index("--size-m") + 1]) == pytest.approx(0.3, rel=1e-4)
    assert command[command.index("--seed") + 1] == "5" and command[-1] == "--no-render"
    for assignment in ("storm.intensity=moderate", "storm.kind=freezing_rain", *FAST.split()):
        assert command[command.index(assignment) - 1] == "--set"
    assert out["exported"]
    assert out["render_command"] == ["icefarm", "run", "in.glb", "-o", "out", "--size-m", "2.5", "--seed", "1",
                                     "--placement", "hanging", "--set", "storm.intensity=severe",
                                     "--set", "storm.kind=meltwater", "--render", "lookdev"]
    # progress: from 0 up to 1, naming the steps as they come
    fractions = [f for f, _ in out["seen"]]
    assert fractions == sorted(fractions[:-1]) + [0.0], "rising, and reset when the operator ends"
    assert max(fractions) > 0.5 and any("surface" in text for _, text in out["seen"])
    assert out["modal_result"] == ["FINISHED"] and out["reports"][-1][0] == "INFO"
    assert "icicles" in out["summary"] and not out["summary"].startswith("ice: 0 ")
    ice = out["ice"]
    assert ice["parent"] == "bunny" and ice["transmission"] == 1.0 and ice["ior"] == pytest.approx(1.31)
    lo, hi = (list(map(float, v)) for v in (out["bunny_lo"], out["bunny_hi"]))
    assert lo[0] > 1.3, "the bunny moved 1 m along x while its ice grew"
    for axis in range(3):  # around the bunny where it is now, within 3 cm; nothing under its ground
        assert lo[axis] - 0.03 < ice["world_lo"][axis] and ice["world_hi"][axis] < hi[axis] + 0.03
    assert ice["world_lo"][2] > lo[2] - 0.002
    # cancel
    assert out["cancelled_in"] == "surface" and out["running_before_cancel"]
    assert out["cancel_result"] == ["CANCELLED"] and out["cancel_reports"][0][0] == "WARNING"
    assert out["returncode"] is not None and not out["group_left"], "the icefarm process and its group are gone"
    assert out["after"] == out["before"], "nothing made, the temporary files removed"
    assert out["active"] == 0 and out["cancel_seconds"] < 5


def test_bad_input_reports_one_error_and_makes_nothing(tmp_path):
    """Nothing selected, a camera, a mesh with no faces, an icefarm that fails, one that is
    not there, and icefarm refusing a setting: one ERROR line each, nothing added to the
    file, no temporary folder left. The add-on is installed from its zip here too."""
    from icefarm.dcc.addon_zip import write_blender_addon

    failing = tmp_path / "failing-icefarm"
    failing.write_text("#!/bin/sh\necho 'prepare ...'\necho 'warning: a warning first' >&2\n"
                       "echo 'error: the storm blew the mesh away' >&2\nexit 1\n")
    failing.chmod(0o755)
    out, _ = run_blender(tmp_path, "bad_input", failing=str(failing), missing=str(tmp_path / "no-icefarm"),
                         zip=str(write_blender_addon(tmp_path / "dist" / "icefarm_blender.zip")))
    assert Path(out["installed_in"]).is_relative_to(tmp_path / "blender-user")
    expected = {"nothing selected": "select one or more mesh objects",
                "a camera": "Camera is a camera, not a mesh",
                "no faces": "points has no faces",
                "a failing icefarm": "icefarm error: the storm blew the mesh away",
                "no such icefarm": "cannot run icefarm",
                "an unknown setting": "icefarm error: unknown parameter"}
    # the panel, drawn on a recording layout (Blender draws none in background mode)
    assert out["panel"][:4] == ["prop intensity", "prop kind", "prop seed", "prop placement"]
    assert "label Cube: about 1 m tall" in out["panel"] and out["panel"][-1] == "operator icefarm.grow"
    assert out["panel_running"] == ["progress 0.25 Cube (1/1): surface", "operator icefarm.cancel"]
    assert out["preferences"] == ["prop executable", f"label runs: {ICEFARM}"]
    for name, case in out["cases"].items():
        assert len(case["reports"]) == 1 and case["reports"][0].startswith("Error: "), (name, case)
        assert expected[name] in case["reports"][0], (name, case)
        assert case["unchanged"], name
