// The compact ray queue of the compute stage (hybrid_shadow_addon/core/gpu/passes/queue.py).
//
// A generating kernel (one invocation per texel, 8x8 groups) appends the texels that need a ray
// (hs_enqueue, hs_queue_append);
// a tracing kernel, dispatched indirectly with the group count the appends left in the head,
// takes one queued texel per invocation, so its lanes are full of rays whatever the texels
// around them needed. The head's count and group count are the GPU's own: no read-back sizes
// the work.
//
// Binding 0, the head: the texels queued, then the tracing kernel's indirect dispatch
// arguments (groups x, y, z; the host sets y = z = 1 and the rest 0 before the generating
// kernel). Binding 1: the queued texels, x | y << 16.
// Defines: HS_QUEUE_GEN (the generating kernel), else the tracing kernel; HS_QUEUE_LANES
// (tracing): invocations per queued texel, neighbours in one group (the generating kernel is
// told by u_queue_per_group, the texels a tracing group takes).

#define HS_QUEUE_GROUP 64   // invocations of a tracing group (queue.py: QUEUE_GROUP)

layout(std430, binding = 0) buffer hs_queue_head { uint hs_queue_count; uint hs_queue_groups[3]; };
layout(std430, binding = 1) buffer hs_queue_items { uint hs_queue_item[]; };

#ifdef HS_QUEUE_LANES
#define HS_QUEUE_PER_TEXEL HS_QUEUE_LANES
#else
#define HS_QUEUE_PER_TEXEL 1
#endif

#ifdef HS_QUEUE_GEN
layout(local_size_x = 8, local_size_y = 8) in;
uniform uint u_queue_per_group;  // queued texels per tracing group: HS_QUEUE_GROUP / its lanes
#else
layout(local_size_x = HS_QUEUE_GROUP) in;
uniform uint u_queue_first;    // the first queued texel of this dispatch (a final render's slices)
#endif

bool hs_queued = false;         // this invocation's texel goes to the queue (nothing to store)

// The texel of this invocation joins the queue (hs_queue_append appends it).
void hs_enqueue() { hs_queued = true; }

#ifdef HS_QUEUE_GEN
// Append texel t to the queue if it joined; the tracing kernel's group count follows the
// queue's length. (One atomic per texel: llvmpipe runs a group's barriers slowly, so a
// group-wide append costs it more than it saves; GPUs merge a warp's atomics on one address.)
void hs_queue_append(ivec2 t)
{
    if (!hs_queued) return;
    uint i = atomicAdd(hs_queue_count, 1u);
    hs_queue_item[i] = uint(t.x) | (uint(t.y) << 16);
    if (i % u_queue_per_group == 0u) atomicMax(hs_queue_groups[0], i / u_queue_per_group + 1u);
}
#endif

#ifndef HS_QUEUE_GEN
// This invocation's queued texel; false past the queue's end.
bool hs_dequeue(out ivec2 t)
{
    uint i = u_queue_first + gl_GlobalInvocationID.x / uint(HS_QUEUE_PER_TEXEL);
    t = ivec2(0);
    if (i >= hs_queue_count) return false;
    uint e = hs_queue_item[i];
    t = ivec2(int(e & 0xffffu), int(e >> 16));
    return true;
}
#endif
