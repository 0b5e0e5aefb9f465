// A small stand-in for Flamenco Manager's job-compiler API (author.Task, author.Command,
// frameChunker, path, print, formatTimestampLocal): loads a job type file, fills the job's
// settings with their defaults, runs compileJob and prints the tasks as JSON on stdout.
//
//   node tests/flamenco_stub.js JOB_TYPE.js JOB.json
//
// JOB.json: {"name": ..., "created": ISO time, "settings": {...}}. A thrown error prints
// {"error": "..."} and exits with code 3.
"use strict";
const fs = require("fs");
const vm = require("vm");
const nodePath = require("path");

function parseFrames(text) {
    const frames = [];
    for (const part of String(text).split(",")) {
        const p = part.trim();
        if (!p) continue;
        const m = p.match(/^(-?\d+)(?:\s*-\s*(-?\d+))?$/);
        if (!m) throw `invalid frame range "${p}"`;
        const a = parseInt(m[1], 10), b = m[2] === undefined ? a : parseInt(m[2], 10);
        if (b < a) throw `frame range "${p}" ends before it starts`;
        for (let f = a; f <= b; f++) frames.push(f);
    }
    if (!frames.length) throw `empty frame range "${text}"`;
    return frames;
}

function compress(frames) {  // [1,2,3,5] -> "1-3,5"
    const out = [];
    let start = frames[0], prev = frames[0];
    for (const f of frames.slice(1).concat([null])) {
        if (f !== null && f === prev + 1) { prev = f; continue; }
        out.push(start === prev ? `${start}` : `${start}-${prev}`);
        start = prev = f;
    }
    return out.join(",");
}

function frameChunker(frames, chunkSize) {
    const all = parseFrames(frames);
    const size = Math.max(1, parseInt(chunkSize, 10) || 1);
    const chunks = [];
    for (let i = 0; i < all.length; i += size) chunks.push(compress(all.slice(i, i + size)));
    return chunks;
}

class Task {
    constructor(name, type) {
        this.name = name; this.type = type; this.commands = []; this.dependencies = [];
    }
    addCommand(cmd) { this.commands.push(cmd); }
    addDependency(task) { this.dependencies.push(task.name); }
}

const author = {
    Task: (name, type) => new Task(name, type),
    Command: (type, parameters) => ({ type, parameters }),
};

function formatTimestampLocal(date) {
    const d = new Date(date);
    const z = (n) => String(n).padStart(2, "0");
    return `${d.getFullYear()}-${z(d.getMonth() + 1)}-${z(d.getDate())}_${z(d.getHours())}${z(d.getMinutes())}${z(d.getSeconds())}`;
}

const path = {
    join: (...parts) => nodePath.posix.join(...parts),
    dirname: (p) => nodePath.posix.dirname(p),
    basename: (p) => nodePath.posix.basename(p),
    stem: (p) => nodePath.posix.parse(p).name,
};

function main() {
    const [jobTypeFile, jobFile] = process.argv.slice(2);
    const source = fs.readFileSync(jobTypeFile, "utf8");
    const spec = JSON.parse(fs.readFileSync(jobFile, "utf8"));
    const context = vm.createContext({
        author, frameChunker, formatTimestampLocal, path,
        print: (...args) => process.stderr.write(args.map(String).join(" ") + "\n"),
    });
    const { JOB_TYPE, compileJob } = vm.runInContext(source + "\n;({JOB_TYPE, compileJob});", context,
                                                     { filename: jobTypeFile });
    const settings = {};
    for (const s of JOB_TYPE.settings) {
        if (s.key in (spec.settings || {})) settings[s.key] = spec.settings[s.key];
        else if ("default" in s) settings[s.key] = s.default;
        else if (s.required) throw `job setting "${s.key}" is required`;
    }
    const job = {
        name: spec.name || "job", created: spec.created || new Date().toISOString(), settings, tasks: [],
        addTask(t) { this.tasks.push(t); },
    };
    compileJob(job);
    process.stdout.write(JSON.stringify({
        label: JOB_TYPE.label,
        setting_keys: JOB_TYPE.settings.map((s) => s.key),
        settings: job.settings,
        tasks: job.tasks.map((t) => ({ name: t.name, type: t.type, commands: t.commands, dependencies: t.dependencies })),
    }, null, 1) + "\n");
}

try {
    main();
} catch (e) {
    process.stdout.write(JSON.stringify({ error: String(e && e.message ? e.message : e) }) + "\n");
    process.exit(3);
}
