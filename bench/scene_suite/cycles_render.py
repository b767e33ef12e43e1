"""Renders one suite scene with Blender Cycles (run by suite.py):

    blender -b --factory-startup -P bench/scene_suite/cycles_render.py -- JOB.json

JOB.json: {"gltf": path | null, "lecture": scene JSON | null, "env": {"file", "intensity",
"rotation_deg"} | null, "width", "height", "spp", "depth", "threads" (0 = all), "seed",
"out"}. Prints "SUITE_RENDER_SECONDS <s>": the wall time of bpy.ops.render.render (scene
sync, BVH build, path tracing and the EXR write; not Blender's start-up or the glTF import).

The mapping (docs/lighting.md, "Scene suite"):
* tally's max_depth d (1 = direct light) is Cycles' max_bounces d - 1 (every per-kind
  bounce limit as high); no clamping, no Filter Glossy, no denoising, no adaptive sampling,
  box pixel filter of width 1 px (tally: one uniform jitter inside the pixel);
* Principled BSDFs (the glTF importer's) get distribution GGX; Lambert materials of the
  lecture scene are Diffuse BSDFs (roughness 0 = Lambert);
* emission strength = tally's radiance (glTF emissiveFactor x emissiveStrength); a
  one-sided emitter (glTF doubleSided false, tally's default) gets strength x (1 - Backfacing),
  since Cycles' mesh emission is two-sided;
* the camera's vertical field of view (tally's fov_deg, glTF yfov) with sensor fit VERTICAL;
* the environment map: Environment Texture, Closest interpolation (tally: nearest texel),
  Background strength = intensity, Mapping rotation about Blender's z (= glTF/tally +y) of
  90 deg - rotation_deg: tally's u = 0 looks along -z (glTF), which the importer's y-up to
  z-up conversion makes Blender's +y, where Blender's equirectangular u is 0.25.
"""
import json
import math
import sys
import time

import bpy
import mathutils

job = json.load(open(sys.argv[sys.argv.index("--") + 1]))

bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene


def one_sided_emission(mat, strength_socket, strength):
    nt = mat.node_tree
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    front = nt.nodes.new("ShaderNodeMath")
    front.operation = "SUBTRACT"
    front.inputs[0].default_value = 1.0
    nt.links.new(geo.outputs["Backfacing"], front.inputs[1])
    mul = nt.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = strength
    nt.links.new(front.outputs[0], mul.inputs[0])
    nt.links.new(mul.outputs[0], strength_socket)


if job.get("gltf"):
    # Debian's Blender 3.4 glTF importer uses np.bool, which numpy >= 1.24 (Debian 12's)
    # no longer has: give it back the alias (what it always meant: the builtin bool).
    import numpy
    if not hasattr(numpy, "bool") or "bool" in getattr(numpy, "__former_attrs__", {}):
        numpy.bool = bool
    doc = json.load(open(job["gltf"]))
    bpy.ops.import_scene.gltf(filepath=job["gltf"])
    double_sided = {m.get("name"): bool(m.get("doubleSided", False)) for m in doc.get("materials", [])}
    lambert = {m.get("name") for m in doc.get("materials", [])
               if m.get("extensions", {}).get("KHR_materials_specular", {}).get("specularFactor", 1.0) == 0.0}
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        for node in list(mat.node_tree.nodes):
            if node.type == "BSDF_PRINCIPLED" and mat.name in lambert:
                # specularFactor 0 (the suite's model check): tally's pure Lambert = a
                # Diffuse BSDF of roughness 0 with the same base colour (factor or texture).
                nt = mat.node_tree
                d = nt.nodes.new("ShaderNodeBsdfDiffuse")
                d.inputs["Roughness"].default_value = 0.0
                bc = node.inputs["Base Color"]
                d.inputs["Color"].default_value = bc.default_value
                for link in list(bc.links):
                    nt.links.new(link.from_socket, d.inputs["Color"])
                for link in list(node.outputs[0].links):
                    nt.links.new(d.outputs[0], link.to_socket)
                nt.nodes.remove(node)
            elif node.type == "BSDF_PRINCIPLED":
                node.distribution = "GGX"
                es = node.inputs["Emission Strength"]
                em = node.inputs["Emission"]
                emissive = es.default_value > 0 and (em.is_linked or any(c > 0 for c in em.default_value[:3]))
                if emissive and not double_sided.get(mat.name, False) and not es.is_linked:
                    one_sided_emission(mat, es, es.default_value)
    cams = [o for o in sc.objects if o.type == "CAMERA"]
    cam = cams[0]
    yfov = doc["cameras"][0]["perspective"]["yfov"]
    cam.data.sensor_fit = "VERTICAL"
    cam.data.angle_y = yfov
    cam.data.clip_start = 1e-3
    sc.camera = cam
else:
    spec = job["lecture"]

    def diffuse(name, albedo):
        m = bpy.data.materials.new(name)
        m.use_nodes = True
        nt = m.node_tree
        nt.nodes.clear()
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Color"].default_value = tuple(albedo) + (1.0,)
        d.inputs["Roughness"].default_value = 0.0
        o = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(d.outputs[0], o.inputs[0])
        return m

    def emissive(name, radiance, two_sided):
        m = bpy.data.materials.new(name)
        m.use_nodes = True
        nt = m.node_tree
        nt.nodes.clear()
        e = nt.nodes.new("ShaderNodeEmission")
        s = max(radiance)
        e.inputs["Color"].default_value = tuple(c / s for c in radiance) + (1.0,)
        e.inputs["Strength"].default_value = s
        o = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(e.outputs[0], o.inputs[0])
        if not two_sided:
            one_sided_emission(m, e.inputs["Strength"], s)
        return m

    mats = {}
    for name, m in spec["materials"].items():
        if m["type"] == "diffuse":
            mats[name] = diffuse(name, m["albedo"])
        elif m["type"] == "emissive":
            mats[name] = emissive(name, m["radiance"], m.get("two_sided", False))
        else:
            raise SystemExit("lecture scene: material type %s not mapped" % m["type"])
    for k, s in enumerate(spec["shapes"]):
        if s["type"] != "quad":
            raise SystemExit("lecture scene: shape type %s not mapped" % s["type"])
        c, u, v = (mathutils.Vector(s[f]) for f in ("corner", "edge_u", "edge_v"))
        me = bpy.data.meshes.new("q%d" % k)
        me.from_pydata([c, c + u, c + u + v, c + v], [], [(0, 1, 2, 3)])
        ob = bpy.data.objects.new("q%d" % k, me)
        ob.data.materials.append(mats[s["material"]])
        sc.collection.objects.link(ob)
    c = spec["camera"]
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.location = c["position"]
    if list(c.get("up", [0, 1, 0])) != [0, 0, 1]:
        raise SystemExit("lecture scene: only a +z up vector is mapped (Blender's up)")
    # The camera's -Z looks at look_at, its local +Y is kept towards the world's +Z.
    cam.rotation_euler = (mathutils.Vector(c["look_at"]) - cam.location).to_track_quat("-Z", "Y").to_euler()
    cam.data.sensor_fit = "VERTICAL"
    cam.data.angle_y = math.radians(c.get("fov_deg", 45.0))
    cam.data.clip_start = 1e-3

world = bpy.data.worlds.new("world")
sc.world = world
world.use_nodes = True
nt = world.node_tree
nt.nodes.clear()
bg = nt.nodes.new("ShaderNodeBackground")
out = nt.nodes.new("ShaderNodeOutputWorld")
nt.links.new(bg.outputs[0], out.inputs[0])
env = job.get("env")
if env:
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(env["file"])
    tex.image.colorspace_settings.name = "Linear"
    tex.interpolation = "Closest"
    tex.projection = "EQUIRECTANGULAR"
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(env.get("rotation_z_deg", 90.0 - env.get("rotation_deg", 0.0))))
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs[0], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = env.get("intensity", 1.0)
else:
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0

sc.render.engine = "CYCLES"
cy = sc.cycles
cy.device = "CPU"
cy.samples = int(job["spp"])
cy.use_adaptive_sampling = False
cy.use_denoising = False
cy.seed = int(job.get("seed", 0))
b = max(0, int(job["depth"]) - 1)
cy.max_bounces = b
cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = cy.volume_bounces = b
cy.transparent_max_bounces = max(b, 8)
cy.sample_clamp_direct = 0.0
cy.sample_clamp_indirect = 0.0
cy.blur_glossy = 0.0
cy.caustics_reflective = True
cy.caustics_refractive = True
cy.pixel_filter_type = "BOX"
cy.filter_width = 1.0
cy.film_exposure = 1.0
sc.view_settings.view_transform = "Standard"
sc.view_settings.look = "None"
if int(job.get("threads", 0)) > 0:
    sc.render.threads_mode = "FIXED"
    sc.render.threads = int(job["threads"])
else:
    sc.render.threads_mode = "AUTO"
sc.render.resolution_x = int(job["width"])
sc.render.resolution_y = int(job["height"])
sc.render.resolution_percentage = 100
sc.render.film_transparent = False
sc.render.image_settings.file_format = "OPEN_EXR"
sc.render.image_settings.color_depth = "32"
sc.render.image_settings.color_mode = "RGB"
sc.render.filepath = job["out"]
sc.render.use_file_extension = False
t0 = time.perf_counter()
bpy.ops.render.render(write_still=True)
print("SUITE_RENDER_SECONDS %.6f" % (time.perf_counter() - t0), flush=True)
