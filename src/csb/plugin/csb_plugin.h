/* csb — the C interface of a method brought as a plug-in: a shared library that csb loads at
 * run time (csb.load_plugin(path) in Python) and steps like a built-in method, without csb being
 * rebuilt. The interface is plain C, so a plug-in depends on neither csb's C++ ABI, its compiler,
 * its standard library nor its Eigen: it may be written in C, in C++ (export the functions with
 * extern "C"; this header is extern "C" already) or in anything that exports C functions.
 *
 * A plug-in exports these six functions (below, "The entry points"):
 *
 *   int          csb_plugin_abi_version(void);          return CSB_PLUGIN_ABI_VERSION
 *   const char*  csb_plugin_name(void);                 "my-pbd": a short name for tables
 *   void*        csb_plugin_create(const csb_settings*, char* error, size_t error_size);
 *   int          csb_plugin_step(void* handle, const csb_model_view*, csb_state_view*, int64_t steps,
 *                                char* error, size_t error_size);
 *   void         csb_plugin_destroy(void* handle);
 *
 * What csb guarantees a plug-in:
 *   - csb_plugin_abi_version is called first, once per load; any other answer than the
 *     CSB_PLUGIN_ABI_VERSION csb was built with refuses the library (csb.ParameterError naming
 *     the file and both versions): rebuild the plug-in against the header csb installs
 *     (csb.plugin_include_dir() in Python).
 *   - csb_plugin_create gets settings csb has checked (dt > 0 and finite, substeps >= 1,
 *     iterations >= 1, gravity finite); it is called once per integrator made, and
 *     csb_plugin_destroy once for each handle it returned.
 *   - A handle is used by one thread at a time (a second thread stepping the same integrator is
 *     refused by csb before it reaches the plug-in); different handles may be stepped at once
 *     from different threads, so a plug-in keeps its state in its handle, not in globals.
 *   - The arrays of the views are valid for the duration of the call only. The model's arrays
 *     are read-only; a model never changes once built, and model_id tells models apart (a
 *     plug-in may cache per-model data keyed by it, but must not keep the pointers).
 *   - csb advances the state's time and step count itself, checks after each call that every
 *     position and velocity is finite, and on a failed call or a non-finite value puts the state
 *     back where it was before the call: a plug-in need not undo a failed step.
 *
 * What a plug-in promises csb:
 *   - to advance positions and velocities by `steps` steps of dt, in place, and nothing else;
 *   - to report failure by its return value and a message, never by a C++ exception crossing
 *     the interface (catch everything in csb_plugin_step), nor by exiting or aborting the process;
 *   - to refuse, with CSB_PLUGIN_BAD_INPUT and a message, a model it cannot step (constraints it
 *     does not project, say: the num_* counts below tell what the model holds).
 *
 * Units are SI throughout: m, kg, s. Arrays of points are contiguous doubles, x y z per point:
 * point i is at [3 i], [3 i + 1], [3 i + 2].
 */
#ifndef CSB_PLUGIN_H
#define CSB_PLUGIN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The version of this interface: the layout of the structs below and the signatures of the
 * entry points. csb refuses a plug-in that reports another. */
#define CSB_PLUGIN_ABI_VERSION 1

/* What csb_plugin_step returns. */
#define CSB_PLUGIN_OK 0
/* The model or the settings cannot be stepped by this plug-in: csb.ParameterError (a ValueError). */
#define CSB_PLUGIN_BAD_INPUT 1
/* The simulation went wrong (diverged, a solver failed): csb.SimulationError (a RuntimeError).
 * Any other non-zero value is reported as a SimulationError too, with the value. */
#define CSB_PLUGIN_FAILED 2

/* The settings an integrator is made from (csb.load_plugin(path)(dt=..., substeps=...,
 * iterations=..., gravity=...)); a plug-in reads what applies to it. */
typedef struct csb_settings {
  int32_t abi_version;  /* CSB_PLUGIN_ABI_VERSION */
  double dt;            /* s, the time one step advances; > 0 */
  int32_t substeps;     /* sub-steps of dt / substeps per step; >= 1 */
  int32_t iterations;   /* constraint sweeps per sub-step; >= 1 */
  double gravity[3];    /* m/s², the acceleration of every particle of non-zero inverse mass */
} csb_settings;

/* The model, read-only: csb's Model as arrays. */
typedef struct csb_model_view {
  int32_t abi_version;    /* CSB_PLUGIN_ABI_VERSION */
  uint64_t model_id;      /* unique per model built in this process */
  int64_t num_particles;  /* n */
  const double* mass;            /* kg, n values, > 0 (pinned particles keep theirs) */
  const double* inv_mass;        /* 1/kg, n values; 0 for a pinned particle (it must not move) */
  const double* rest_positions;  /* m, 3 n values */

  /* Distance constraints C = |x_i - x_j| - rest_length (stretch edges, links of a chain). */
  int64_t num_distance;
  const int32_t* distance_particles;   /* 2 per constraint: i0 j0 i1 j1 ... (particle indices) */
  const double* distance_rest_length;  /* m, > 0 */
  const double* distance_compliance;   /* m/N, >= 0: XPBD's α (Macklin et al. 2016); 0 is rigid */
  const double* distance_stiffness;    /* dimensionless, in [0, 1]: PBD's k (Müller et al. 2007) */
  const int8_t* distance_sense;        /* 0: C = 0; +1: C >= 0 (only pushes); -1: C <= 0 (only pulls) */

  /* The model's other constraints, counted but not given as arrays in this version: a plug-in
   * that does not project them refuses a model that has any (CSB_PLUGIN_BAD_INPUT). */
  int64_t num_bending;      /* dihedral bending between two triangles */
  int64_t num_volume;       /* tetrahedron volumes */
  int64_t num_balloons;     /* closed surfaces' enclosed volumes */
  int64_t num_attachments;  /* particles tied to points in space */
  int64_t num_other;        /* constraints of csb's other families (tethers, ...) */
  int64_t num_colliders;    /* static colliders (planes, spheres, boxes, ...) */
} csb_model_view;

/* The state, in place: positions and velocities the plug-in advances. */
typedef struct csb_state_view {
  int32_t abi_version;    /* CSB_PLUGIN_ABI_VERSION */
  int64_t num_particles;  /* n, as the model's */
  double t;               /* s, the time at the start of the call (read-only: csb advances it) */
  int64_t step;           /* steps completed before the call (read-only: csb advances it) */
  double* positions;      /* m, 3 n values */
  double* velocities;     /* m/s, 3 n values */
} csb_state_view;

/* The entry points, as a plug-in defines them (CSB_PLUGIN_EXPORT makes them visible even when
 * the library is compiled with -fvisibility=hidden). */
#if defined(_WIN32)
#define CSB_PLUGIN_EXPORT __declspec(dllexport)
#else
#define CSB_PLUGIN_EXPORT __attribute__((visibility("default")))
#endif

/* Returns CSB_PLUGIN_ABI_VERSION as the plug-in was compiled. */
CSB_PLUGIN_EXPORT int csb_plugin_abi_version(void);
/* A short name of the method, for tables and messages ("my-pbd"); a string the library owns,
 * valid while it is loaded. */
CSB_PLUGIN_EXPORT const char* csb_plugin_name(void);
/* Makes an integrator with these settings: a handle csb passes back, or NULL after writing why
 * (a NUL-terminated message of at most error_size bytes) to `error`; csb raises
 * csb.ParameterError with it. */
CSB_PLUGIN_EXPORT void* csb_plugin_create(const csb_settings* settings, char* error, size_t error_size);
/* Advances `state` of `model` by `steps` >= 1 steps of dt. Returns CSB_PLUGIN_OK, or an error
 * code (CSB_PLUGIN_BAD_INPUT, CSB_PLUGIN_FAILED) after writing a NUL-terminated message of at
 * most error_size bytes to `error`. */
CSB_PLUGIN_EXPORT int csb_plugin_step(void* handle, const csb_model_view* model, csb_state_view* state,
                                      int64_t steps, char* error, size_t error_size);
/* Frees what csb_plugin_create made. */
CSB_PLUGIN_EXPORT void csb_plugin_destroy(void* handle);

/* The entry points' types, for the loader. */
typedef int (*csb_plugin_abi_version_fn)(void);
typedef const char* (*csb_plugin_name_fn)(void);
typedef void* (*csb_plugin_create_fn)(const csb_settings*, char*, size_t);
typedef int (*csb_plugin_step_fn)(void*, const csb_model_view*, csb_state_view*, int64_t, char*, size_t);
typedef void (*csb_plugin_destroy_fn)(void*);

#ifdef __cplusplus
}
#endif

#endif /* CSB_PLUGIN_H */
