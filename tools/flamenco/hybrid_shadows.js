// SPDX-License-Identifier: GPL-3.0-or-later
//
// Flamenco job type: render a frame range with the Hybrid Shadows engine (HYBRID_SHADOWS),
// in chunks of frames, one Blender per chunk. Within a chunk the engine keeps its bake
// between frames (persistent data), so each task bakes once. See README.md next to this file.

const HYBRID_SHADOW_MODES = ["RAYTRACE", "SHADOWMAP", "NONE"];
const HYBRID_SHADOW_QUALITIES = ["HIGH", "MEDIUM", "LOW"];

const JOB_TYPE = {
    label: "Hybrid Shadows Render",
    description: "Render a sequence of frames with the Hybrid Shadows engine (ray-traced or shadow-mapped, " +
                 "soft or hard shadows)",
    settings: [
        // Settings for artists to determine:
        { key: "frames", type: "string", required: true,
          eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
          evalInfo: { showLinkButton: true, description: "Scene frame range" },
          description: "Frame range to render. Examples: '47', '1-30', '3, 5-10, 47-327'" },
        { key: "chunk_size", type: "int32", default: 10, propargs: { min: 1 },
          description: "Frames per render task; each task bakes once and updates the bake between its frames",
          visible: "submission" },
        { key: "shadow_mode", type: "string", required: true, choices: HYBRID_SHADOW_MODES,
          eval: "C.scene.hybrid_shadows.mode", visible: "submission",
          description: "Shadows: RAYTRACE (ray traced), SHADOWMAP (shadow maps) or NONE" },
        { key: "shadow_quality", type: "string", required: true, choices: HYBRID_SHADOW_QUALITIES,
          eval: "C.scene.hybrid_shadows.quality", visible: "submission",
          description: "Ray-traced shadow-mask resolution: HIGH (full), MEDIUM (1/2) or LOW (1/4) per side" },
        { key: "soft_shadows", type: "bool", default: true,
          eval: "C.scene.hybrid_shadows.use_soft_shadows", visible: "submission",
          description: "Soft shadows from the lights' sizes (sun angle, point and spot radius, area size); " +
                       "off: every light casts a hard shadow, one ray towards its centre" },
        { key: "samples", type: "int32", default: 64, propargs: { min: 1, max: 4096 },
          eval: "C.scene.hybrid_shadows.samples", visible: "submission",
          description: "Soft shadows: shadow rays per pixel towards each light with a size (pixels away " +
                       "from any penumbra take 1)" },
        { key: "persistent_bake", type: "bool", default: true, visible: "submission",
          description: "Keep the bake between the frames of a task (Blender's Persistent Data)" },

        // Where the frames go:
        { key: "render_output_root", type: "string", subtype: "dir_path", required: true, visible: "submission",
          description: "Base directory of where render output is stored. Will have some job-specific parts appended to it" },
        { key: "add_path_components", type: "int32", required: true, default: 0, propargs: { min: 0, max: 32 },
          visible: "submission",
          description: "Number of path components of the current blend file to use in the render output path" },
        { key: "render_output_path", type: "string", subtype: "file_path", editable: false,
          eval: "str(Path(abspath(settings.render_output_root), last_n_dir_parts(settings.add_path_components), jobname, '{timestamp}', '######'))",
          description: "Final file path of where render output will be saved; # become the frame number" },

        // Automatically evaluated settings:
        { key: "blendfile", type: "string", required: true, description: "Path of the Blend file to render", visible: "web" },
        { key: "scene", type: "string", required: true, eval: "C.scene.name", visible: "web",
          description: "Name of the scene to render" },
        { key: "format", type: "string", required: true, eval: "C.scene.render.image_settings.file_format", visible: "web" },
        { key: "image_file_extension", type: "string", required: true, eval: "C.scene.render.file_extension", visible: "hidden",
          description: "File extension used when rendering images" },
    ]
};


function compileJob(job) {
    print("Hybrid Shadows render job submitted");
    const settings = job.settings;
    checkSettings(settings);

    const renderOutput = renderOutputPath(job);
    // When the job is looked at later, it shows the render output actually used:
    settings.render_output_path = renderOutput;

    for (const task of authorRenderTasks(settings, renderOutput)) {
        job.addTask(task);
    }
}


function checkSettings(settings) {
    if (!HYBRID_SHADOW_MODES.includes(settings.shadow_mode)) {
        throw `shadow_mode must be one of ${HYBRID_SHADOW_MODES.join(", ")}, not "${settings.shadow_mode}"`;
    }
    if (!HYBRID_SHADOW_QUALITIES.includes(settings.shadow_quality)) {
        throw `shadow_quality must be one of ${HYBRID_SHADOW_QUALITIES.join(", ")}, not "${settings.shadow_quality}"`;
    }
    if (!Number.isInteger(settings.samples) || settings.samples < 1) {
        throw `samples must be a whole number of at least 1, not ${settings.samples}`;
    }
    if (typeof settings.soft_shadows !== "boolean") {
        throw `soft_shadows must be true or false, not ${settings.soft_shadows}`;
    }
    if (!(settings.chunk_size >= 1)) {
        throw `chunk_size must be at least 1, not ${settings.chunk_size}`;
    }
}


// Field replacement on the render output path.
function renderOutputPath(job) {
    const path = job.settings.render_output_path;
    if (!path) {
        throw "no render_output_path setting!";
    }
    if (!path.includes("#")) {
        throw `render_output_path "${path}" has no # for the frame number`;
    }
    return path.replace(/{([^}]+)}/g, (match, group0) => {
        switch (group0) {
        case "timestamp":
            return formatTimestampLocal(job.created);
        default:
            return match;
        }
    });
}


// The Python run before rendering: the engine and its settings on the scene being rendered.
// A failure (the extension missing on the worker) exits Blender with code 1 (--python-exit-code).
function engineSetupExpr(settings) {
    return [
        "import bpy",
        "s = bpy.context.scene",
        "s.render.engine = 'HYBRID_SHADOWS'",
        `s.hybrid_shadows.mode = '${settings.shadow_mode}'`,
        `s.hybrid_shadows.quality = '${settings.shadow_quality}'`,
        `s.hybrid_shadows.use_soft_shadows = ${settings.soft_shadows ? "True" : "False"}`,
        `s.hybrid_shadows.samples = ${settings.samples}`,
        `s.render.use_persistent_data = ${settings.persistent_bake ? "True" : "False"}`,
    ].join("; ");
}


function authorRenderTasks(settings, renderOutput) {
    const tasks = [];
    const chunks = frameChunker(settings.frames, settings.chunk_size);
    for (const chunk of chunks) {
        const task = author.Task(`render-${chunk}`, "blender");
        let args = [];
        if (settings.scene) {
            args = args.concat(["--scene", settings.scene]);
        }
        args = args.concat([
            "-E", "HYBRID_SHADOWS",
            "--python-exit-code", "1",
            "--python-expr", engineSetupExpr(settings),
            "--render-output", renderOutput,
            "--render-format", settings.format,
            "--render-frame", chunk.replaceAll("-", ".."),  // Blender's frame range notation
        ]);
        const command = author.Command("blender-render", {
            exe: "{blender}",
            exeArgs: "{blenderArgs}",
            argsBefore: [],
            blendfile: settings.blendfile,
            args: args,
        });
        task.addCommand(command);
        tasks.push(task);
    }
    return tasks;
}
