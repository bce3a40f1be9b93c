// csb._core: the steppers (PBD, XPBD, Jakobsen; the force-based integrators), tearing, picking,
// and the solver machinery's benchmarks.
#include "bindings.hpp"
#include "bench/dispatch.hpp"
#include "csb/constraints/families.hpp"

namespace csb::python {

void bind_methods(py::module_& m, const Warnings& warnings) {
  // ---------------------------------------------------------------- PBD
  py::class_<PbdSettings>(m, "PbdSettings", "Settings of a position-based stepper (SI units).")
      .def_property_readonly("method", [](const PbdSettings& s) { return method_info(s.method).name; })
      .def_readonly("dt", &PbdSettings::dt, "s, time advanced by one step")
      .def_readonly("substeps", &PbdSettings::substeps)
      .def_readonly("iterations", &PbdSettings::iterations)
      .def_property_readonly("gravity", [](const PbdSettings& s) { return vec3_array(s.gravity); }, "m/s²")
      .def_readonly("damping", &PbdSettings::damping, "Müller 2007 §3.5 k_damping per substep, [0, 1]")
      .def_readonly("stiffness_correction", &PbdSettings::stiffness_correction)
      .def_readonly("max_speed", &PbdSettings::max_speed, "m/s, the divergence guard (0: automatic, inf: off)")
      .def_property_readonly("front_end", [](const PbdSettings& s) { return s.front_end == FrontEnd::Euler ? "euler" : "verlet"; })
      .def_property_readonly("solver", [](const PbdSettings& s) {
        return s.solver == Solver::GaussSeidel ? "gauss-seidel" : s.solver == Solver::Jacobi ? "jacobi" : "jacobi-summed";
      })
      .def_readonly("xpbd_damping", &PbdSettings::xpbd_damping, "XPBD constraint damping β, N s/m")
      .def_readonly("verlet_drag", &PbdSettings::verlet_drag, "Jakobsen's drag d in [0, 1)")
      .def_readonly("sqrt_approximation", &PbdSettings::sqrt_approximation)
      .def_property_readonly("ordering", [](const PbdSettings& s) {
        return s.ordering == Ordering::Coloured ? "coloured" : "sequential";
      })
      .def_readonly("threads", &PbdSettings::threads, "threads that share a sweep (parts and interfaces as tasks); 0: automatic")
      .def_property_readonly("precision", [](const PbdSettings& s) {
        return s.precision == Precision::Single ? "float32" : "float64";
      }, "the solver's scalar: 'float64' or 'float32'")
      .def("__repr__", [](const PbdSettings& s) {
        std::ostringstream o;
        o << "PbdSettings(method='" << method_info(s.method).name << "'"
          << ", dt=" << s.dt << ", substeps=" << s.substeps << ", iterations=" << s.iterations << ", gravity=("
          << s.gravity.x() << ", " << s.gravity.y() << ", " << s.gravity.z() << "), damping=" << s.damping
          << ", stiffness_correction=" << (s.stiffness_correction ? "True" : "False") << ", front_end='"
          << (s.front_end == FrontEnd::Euler ? "euler" : "verlet") << "', solver='"
          << (s.solver == Solver::GaussSeidel ? "gauss-seidel" : s.solver == Solver::Jacobi ? "jacobi" : "jacobi-summed")
          << "', xpbd_damping=" << s.xpbd_damping << ", verlet_drag=" << s.verlet_drag
          << ", sqrt_approximation=" << (s.sqrt_approximation ? "True" : "False") << ", ordering='"
          << (s.ordering == Ordering::Coloured ? "coloured" : "sequential") << "', threads=" << s.threads
          << ", max_speed=" << s.max_speed << ", precision='"
          << (s.precision == Precision::Single ? "float32" : "float64") << "')";
        return o.str();
      });

  py::class_<PbdStepper, Integrator, py::smart_holder>(m, "PbdStepper",
      "Position-based stepper: Müller et al. 2007 PBD, Macklin et al. 2016 XPBD, or Jakobsen 2001 Verlet with relaxation.")
      .def(py::init([](const std::string& method, double dt, IntArg substeps, IntArg iterations, py::handle gravity,
                       double damping, bool stiffness_correction, const std::string& front_end,
                       const std::string& solver, double xpbd_damping, double verlet_drag, bool sqrt_approximation,
                       const std::string& ordering, IntArg threads, double max_speed, const std::string& precision) {
             PbdSettings s;
             s.method = pbd_variant(method);
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
             s.gravity = to_vec3(gravity, "gravity");
             s.damping = damping;
             s.stiffness_correction = stiffness_correction;
             if (front_end == "euler") s.front_end = FrontEnd::Euler;
             else if (front_end == "verlet") s.front_end = FrontEnd::Verlet;
             else if (front_end == "auto") s.front_end = s.method == Method::Jakobsen ? FrontEnd::Verlet : FrontEnd::Euler;
             else throw InvalidArgument("front_end must be 'euler', 'verlet' or 'auto', got '" + front_end + "'");
             if (solver == "gauss-seidel") s.solver = Solver::GaussSeidel;
             else if (solver == "jacobi") s.solver = Solver::Jacobi;
             else if (solver == "jacobi-summed") s.solver = Solver::JacobiSummed;
             else throw InvalidArgument("solver must be 'gauss-seidel', 'jacobi' or 'jacobi-summed', got '" + solver + "'");
             s.xpbd_damping = xpbd_damping;
             s.verlet_drag = verlet_drag;
             s.sqrt_approximation = sqrt_approximation;
             if (ordering == "coloured") s.ordering = Ordering::Coloured;
             else if (ordering == "sequential") s.ordering = Ordering::Sequential;
             else throw InvalidArgument("ordering must be 'coloured' or 'sequential', got '" + ordering + "'");
             s.threads = in_range<int>(threads, "threads", 0, kMaxThreads);
             s.max_speed = max_speed;
             if (precision == "float64") s.precision = Precision::Double;
             else if (precision == "float32") s.precision = Precision::Single;
             else throw InvalidArgument("precision must be 'float64' or 'float32', got '" + precision + "'");
             return PbdStepper(s);
           }),
           py::kw_only(), py::arg("method") = "pbd", py::arg("dt") = 1.0 / 60.0, py::arg("substeps") = 1,
           py::arg("iterations") = 10, py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           py::arg("damping") = 0.0, py::arg("stiffness_correction") = true, py::arg("front_end") = "auto",
           py::arg("solver") = "gauss-seidel", py::arg("xpbd_damping") = 0.0, py::arg("verlet_drag") = 0.0,
           py::arg("sqrt_approximation") = false, py::arg("ordering") = "coloured", py::arg("threads") = 0,
           py::arg("max_speed") = 0.0, py::arg("precision") = "float64",
           "method: 'pbd' (stiffness k), 'xpbd' (compliance α) or 'jakobsen'. dt: time step, s (> 0). substeps: "
           "sub-steps per step, in [1, 10^6]. iterations: constraint sweeps per sub-step, in [1, 10^6]. gravity: m/s². damping: "
           "Müller §3.5 k_damping in [0, 1] per sub-step (Euler front end). stiffness_correction: PBD's "
           "k' = 1 - (1 - k)^(1/iterations). front_end: 'euler' (velocity), 'verlet' (previous position) or 'auto' "
           "(Verlet for Jakobsen). solver: 'gauss-seidel', 'jacobi' (averaged) or 'jacobi-summed'. xpbd_damping: "
           "β, N s/m (XPBD). verlet_drag: Jakobsen's d in [0, 1). sqrt_approximation: Jakobsen's stick relaxation "
           "without square roots. ordering: 'coloured' (the model's parts and interfaces as the "
           "threads' tasks, each batch of a task colour by colour in SIMD lanes) or 'sequential' (as built, one "
           "thread). threads: threads that share a sweep, in [0, 1024] (0: the free cores, at most the model's parts; the "
           "result does not depend on it). max_speed: the divergence guard, m/s: a step after which a movable "
           "particle is faster raises SimulationError naming it (0: automatic, D/h + 2 (v0 + |g| t + sqrt(2 |g| D)) "
           "with D the model's size and v0 the fastest start speed; inf: off). precision: the solver's scalar, "
           "'float64' or 'float32' (the state rounded to float during a step: twice the SIMD lanes, half the bytes; "
           "coloured Gauss-Seidel, distance and bending constraints and pins, without contacts or grabs).")
      .def_property_readonly("settings", &PbdStepper::settings)
      .def_property_readonly("threads_used", &PbdStepper::threads_used, "threads the last step used")
      .def_property_readonly("workspace_bytes", &PbdStepper::workspace_bytes,
                             "bytes of the stepper's per-model workspace (from the vectors' capacities)")
      .def_property_readonly("substep_size", &PbdStepper::substep_size, "h = dt/substeps, s")
      .def("step", [warnings](PbdStepper& s, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        const std::int64_t steps = in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64);
        {
          // Once per model and stepper, at the caller's line: what the method ignores of the material.
          const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.step");
          for (const MaterialNote& note : s.material_notes_to_report(model))
            if (PyErr_WarnEx(warnings.material, note.message.c_str(), 1) < 0) throw py::error_already_set();
          for (const std::string& note : s.accuracy_notes_to_report(model))
            if (PyErr_WarnEx(warnings.accuracy, note.c_str(), 1) < 0) throw py::error_already_set();
          s.material_reported(model);
          for (const std::string& note : s.degenerate_notes_to_report(model, state))
            if (PyErr_WarnEx(warnings.accuracy, note.c_str(), 1) < 0) throw py::error_already_set();
        }
        step_interruptibly(s, model, state, steps, interrupt);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C, or `interrupt` (a callable "
         "asked between sub-steps) returning True, stops it between sub-steps, the state left at the end of the "
         "last completed one; a second thread stepping the same "
         "stepper meanwhile gets csb.ConcurrentUseError). The first time this stepper "
         "steps a model, a csb.MaterialWarning per constraint family whose declared material the method cannot "
         "read: PBD and Jakobsen read the stiffness k, XPBD the compliance α, so constraints with only α > 0 "
         "(k = 1) are rigid under PBD and Jakobsen, those with only k < 1 (α = 0) rigid under XPBD.")
      .def("projections_per_step", &PbdStepper::projections_per_step, py::arg("model"))
      .def("operations", [](const PbdStepper& s, const Model& model, IntArg steps_arg) {
        return s.operations(model, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64));
      }, py::arg("model"), py::arg("steps"),
         "Constraint projections and particle updates of `steps` steps of the model: step() refuses "
         "(csb.ParameterError, with the estimate) a request that would take more than a year at 1e9 a second")
      .def("multipliers", [](const PbdStepper& s) {
        const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.multipliers");
        const Multipliers& l = s.multipliers();
        py::dict d;
        d["distance"] = py::array_t<Real>(static_cast<py::ssize_t>(l.distance.size()), l.distance.data());
        d["bending"] = py::array_t<Real>(static_cast<py::ssize_t>(l.bending.size()), l.bending.data());
        d["attachment"] = py::array_t<Real>(static_cast<py::ssize_t>(l.attachment.size()), l.attachment.data());
        d["volume"] = py::array_t<Real>(static_cast<py::ssize_t>(l.volume.size()), l.volume.data());
        d["balloon"] = py::array_t<Real>(static_cast<py::ssize_t>(l.balloon.size()), l.balloon.data());
        for (std::size_t f = 0; f < l.family.size() && f < families().size(); ++f)
          d[families()[f]->name.c_str()] = py::array_t<Real>(static_cast<py::ssize_t>(l.family[f].size()), l.family[f].data());
        return d;
      }, "XPBD: the Lagrange multipliers λ of the last sub-step per batch and per constraint family (tethers: "
         "λ <= 0) (empty otherwise); the constraint force is λ/h² along ∇C (N for distance constraints and tethers; "
         "for volume and balloon λ/h² is a pressure, Pa).")
      .def("contacts", [](const PbdStepper& s) {
        const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.contacts");
        const ContactSummary& sum = s.contact_summary();
        const auto& c = s.contacts();
        const py::ssize_t m = static_cast<py::ssize_t>(c.size());
        py::array_t<Index> particle(m), collider(m);
        py::array_t<double> point({m, py::ssize_t(3)}), normal({m, py::ssize_t(3)}), correction(m), lambda(m);
        for (py::ssize_t k = 0; k < m; ++k) {
          particle.mutable_at(k) = c[k].particle;
          collider.mutable_at(k) = c[k].collider;
          for (int j = 0; j < 3; ++j) point.mutable_at(k, j) = c[k].point[j], normal.mutable_at(k, j) = c[k].normal[j];
          correction.mutable_at(k) = c[k].normal_correction;
          lambda.mutable_at(k) = c[k].lambda;
        }
        py::dict d;
        d["count"] = sum.count;
        d["active"] = sum.active;
        d["self_count"] = sum.self_count;
        d["self_continuous"] = sum.self_continuous;
        d["self_failsafe"] = sum.self_failsafe;
        d["self_unresolved"] = sum.self_unresolved;
        d["self_searches"] = sum.self_searches;
        d["self_candidates"] = sum.self_candidates;
        d["self_tests"] = sum.self_tests;
        d["self_culled"] = sum.self_culled;
        d["self_skipped"] = sum.self_skipped;
        d["max_depth"] = sum.max_depth;
        d["max_penetration"] = sum.max_penetration;
        d["collider_penetration"] = sum.collider_penetration;
        d["self_penetration"] = sum.self_penetration;
        d["particle"] = particle;
        d["collider"] = collider;
        d["point"] = point;
        d["normal"] = normal;
        d["normal_correction"] = correction;
        d["lambda"] = lambda;
        return d;
      }, "The contacts of the last sub-step: count (particle-collider, speculative ones included), active (those "
         "that pushed their particle), self_count (self-contacts: proximity point-triangle, and continuous), "
         "self_continuous (found by the continuous test), self_failsafe (particles "
         "the fail-safe stopped), self_unresolved (impacts only prescribed particles drive), self_searches (candidate-pair "
         "searches since the stepper was made), self_skipped (triangles left out: spread over more than the cloth's size "
         "within a step), max_depth "
         "(m, deepest violation r - (p - q)·n at the prediction), max_penetration (m, deepest violation left at the "
         "end of the sub-step, thickness included; the larger of collider_penetration, the collider contacts', which "
         "they take last and so leave at round-off, and self_penetration, the self-contacts', which a collider's push "
         "after them may leave thinner than their thickness), and per contact: particle, collider, point q (m), normal n, "
         "normal_correction (m) and lambda (XPBD multiplier, kg m; force λ/h² N).")
      .def("grab", [](PbdStepper& s, const Model& model, const State& state, IntArg particle, py::handle target,
                      double compliance) {
        return s.grab(model, state, index_arg(particle, "grab: particle"), to_vec3(target, "target"), compliance);
      }, py::arg("model"), py::arg("state"), py::arg("particle"), py::arg("target"), py::kw_only(),
         py::arg("compliance") = 0.0,
         "Holds `particle` with the hand at `target` (m) and returns a handle (click and drag). compliance 0: the "
         "particle follows the hand exactly, moved along a straight line over the sub-steps of the next step; "
         "compliance > 0 (m/N): an XPBD spring to the hand. The hand starts where the particle is now.")
      .def("move_grab", [](PbdStepper& s, IntArg handle, py::handle target) {
        s.move_grab(index_arg(handle, "move_grab: handle"), to_vec3(target, "target"));
      },
           py::arg("handle"), py::arg("target"), "Moves the hand of a grab (m); the next step takes the particle there.")
      .def("release", [](PbdStepper& s, IntArg handle) { s.release(index_arg(handle, "release: handle")); }, py::arg("handle"),
           "Lets go of a grab; the particle keeps the velocity it had.")
      .def_property_readonly("grabs", [](const PbdStepper& s) {
        py::list out;
        for (const Grab& g : s.grabs()) {
          if (g.handle < 0) continue;  // a particle attached to a collider (attachments)
          py::dict d;
          d["handle"] = g.handle;
          d["particle"] = g.particle;
          d["target"] = std::vector<double>{g.target.x(), g.target.y(), g.target.z()};
          d["compliance"] = g.compliance;
          out.append(d);
        }
        return out;
      }, "The grabs held now: handle, particle, target (m), compliance (m/N).")
      // Moving colliders and attachments (collision/collider_motion.cpp).
      .def("move_collider", [](PbdStepper& s, const Model& model, IntArg collider, py::handle rotation,
                               py::handle translation) {
        const Index c = index_arg(collider, "move_collider: collider");
        const std::string what = "move_collider: collider " + std::to_string(c);
        s.move_collider(model, c, to_mat3(rotation, what + ": rotation"), to_vec3(translation, what + ": translation"));
      }, py::arg("model"), py::arg("collider"), py::arg("rotation"), py::arg("translation"),
         "Sets the pose collider `collider` reaches at the end of the next step: x_world = rotation x_model + "
         "translation (rotation a 3 x 3 rotation matrix, orthonormal with det +1 to 1e-6; translation in m). Over the "
         "step's sub-steps it moves there from its present pose (translation linearly, rotation by quaternion slerp, "
         "so less than π a step); contacts see the motion relative to it, friction and restitution the relative "
         "velocity. Every collider starts at the identity.")
      .def("collider_pose", [](const PbdStepper& s, IntArg collider) {
        const ColliderPose p = s.collider_pose(index_arg(collider, "collider_pose: collider"));
        py::array_t<double> r({py::ssize_t(3), py::ssize_t(3)});
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) r.mutable_at(i, j) = p.rotation(i, j);
        return py::make_tuple(r, vec3_array(p.translation));
      }, py::arg("collider"), "The pose (rotation, translation in m) of a collider at the end of the last step.")
      .def("attach", [](PbdStepper& s, const Model& model, const State& state, IntArg collider, py::iterable particles) {
        std::vector<Index> ids;
        for (py::handle h : particles) ids.push_back(index_arg(h.cast<IntArg>(), "attach: particle"));
        s.attach(model, state, index_arg(collider, "attach: collider"), ids);
      }, py::arg("model"), py::arg("state"), py::arg("collider"), py::arg("particles"),
         "Attaches particles to collider `collider`: kinematic while attached (inverse mass 0 in the projections), "
         "each placed at the collider's pose, interpolated over the sub-steps, applied to where it is in the "
         "collider's frame now (a cape on a moving character's shoulders).")
      .def("detach", [](PbdStepper& s, IntArg collider, std::optional<py::iterable> particles) {
        std::vector<Index> ids;
        if (particles)
          for (py::handle h : *particles) ids.push_back(index_arg(h.cast<IntArg>(), "detach: particle"));
        s.detach(index_arg(collider, "detach: collider"), ids);
      }, py::arg("collider"), py::arg("particles") = py::none(),
         "Lets go of `particles` attached to collider `collider` (all of them if None); they keep their velocity.")
      .def_property_readonly("attachments", [](const PbdStepper& s) {
        py::list out;
        for (const ColliderAttachment& a : s.attachments()) {
          py::dict d;
          d["collider"] = a.collider;
          d["particle"] = a.particle;
          d["local"] = std::vector<double>{a.local.x(), a.local.y(), a.local.z()};
          d["triangle"] = a.triangle;
          d["frame"] = std::vector<double>{a.frame.x(), a.frame.y(), a.frame.z()};
          out.append(d);
        }
        return out;
      }, "The particles attached to colliders: collider, particle, local (m, its position in the collider's frame); "
         "on a mesh collider also triangle (the nearest when attached, -1 otherwise) and frame (u, v, w): local = a + "
         "u (b - a) + v (c - a) + w n in that triangle (w in m), the point that follows the mesh when it deforms.")
      .def("deform_collider", [](PbdStepper& s, const Model& model, IntArg collider, py::handle vertices) {
        const Index c = index_arg(collider, "deform_collider: collider");
        s.deform_collider(model, c, to_positions(vertices, "deform_collider: collider " + std::to_string(c) + ": vertices"));
      }, py::arg("model"), py::arg("collider"), py::arg("vertices"),
         "Sets the vertices (V x 3, m, the collider's model frame, in the order of model.colliders[collider]"
         "['vertices']) mesh collider `collider` reaches at the end of the next step: each moves there on a straight "
         "line over the step's sub-steps (then carried by its pose, if moved). Particles are tested against the moving "
         "triangles continuously; friction and restitution see the surface's velocity; attached particles follow "
         "their triangle. The first call deforms from the model's vertices.")
      .def("collider_vertices", [](const PbdStepper& s, const Model& model, IntArg collider) {
        const Positions v = s.collider_vertices(model, index_arg(collider, "collider_vertices: collider"));
        py::array_t<double> out({static_cast<py::ssize_t>(v.cols()), py::ssize_t(3)});
        if (v.cols()) std::memcpy(out.mutable_data(), v.data(), sizeof(double) * v.size());
        return out;
      }, py::arg("model"), py::arg("collider"),
         "A mesh collider's vertices (V x 3, m, model frame) at the end of the last step: the model's until deformed.");

  m.def("tear", [](py::object model_obj, py::object state_obj, double max_strain, IntArg max_tears_arg) {
    const Model& model = model_obj.cast<const Model&>();
    const Index max_tears = in_range(max_tears_arg, "tear: max_tears", 1, kMaxIndex);
    // The given state is left as it is (numpy views of it stay valid); a torn one is a copy.
    auto torn_state = std::make_shared<State>(state_obj.cast<const State&>());
    TearResult r;
    {
      py::gil_scoped_release release;
      r = tear(model, *torn_state, max_strain, max_tears);
    }
    py::dict d;
    d["torn"] = r.torn;
    d["split"] = py::array_t<Index>(static_cast<py::ssize_t>(r.split.size()), r.split.data());
    d["model"] = r.torn ? py::cast(std::const_pointer_cast<Model>(r.model)) : model_obj;
    d["state"] = r.torn ? py::cast(torn_state) : state_obj;
    return d;
  }, py::arg("model"), py::arg("state"), py::kw_only(), py::arg("max_strain"), py::arg("max_tears") = 1,
     "Tearing (Müller 2007 §4.6): splits up to max_tears vertices of distance constraints strained past max_strain "
     "(|l - l0|/l0 > 0), most strained first. Returns a dict: torn (how many), split (the particles split), model "
     "and state — new ones if anything tore (the new particles are appended), else the ones given.");

  py::class_<Pick>(m, "Pick", "What a ray cast found: the particle (-1: none), the distance along the ray (m) and "
                               "the surface triangle hit (-1: found by proximity to the ray).")
      .def_readonly("particle", &Pick::particle)
      .def_readonly("distance", &Pick::distance)
      .def_readonly("triangle", &Pick::triangle)
      .def("__repr__", [](const Pick& p) {
        return "Pick(particle=" + std::to_string(p.particle) + ", distance=" + std::to_string(p.distance) +
               ", triangle=" + std::to_string(p.triangle) + ")";
      });
  m.def("pick_particle", [](const Model& model, const State& state, py::handle origin, py::handle direction,
                            double max_distance) {
    return pick_particle(model, state, to_vec3(origin, "origin"), to_vec3(direction, "direction"), max_distance);
  }, py::arg("model"), py::arg("state"), py::arg("origin"), py::arg("direction"), py::kw_only(),
     py::arg("max_distance") = 0.05,
     "The particle under a ray (the cursor): the first surface triangle it crosses, then that triangle's vertex "
     "nearest the hit; without a hit, the particle nearest the ray within max_distance (m).");

  py::class_<ForceStepper, Integrator, py::smart_holder>(m, "ForceStepper",
      "Force-based mass-spring integrators on the reference's spring network (every constraint a spring of "
      "stiffness 1/α): the methods that fail, for the stability studies.")
      .def(py::init([](const std::string& method, double dt, IntArg substeps, py::handle gravity, double damping,
                       double drag) {
             ForceSettings s;
             s.method = force_integrator(method);
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.gravity = to_vec3(gravity, "gravity");
             s.damping = damping;
             s.drag = drag;
             return ForceStepper(s);
           }),
           py::kw_only(), py::arg("method") = "symplectic-euler", py::arg("dt") = 1e-4, py::arg("substeps") = 1,
           py::arg("gravity") = std::vector<double>{0, -9.81, 0}, py::arg("damping") = 0.0, py::arg("drag") = 0.0,
           "method: 'explicit-euler', 'symplectic-euler' or 'velocity-verlet'. dt: s. damping: N s/m along springs. "
           "drag: 1/s.")
      .def("step", [](ForceStepper& s, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        step_interruptibly(s, model, state, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64), interrupt);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C, or `interrupt` (a callable "
         "asked between steps) returning True, stops it between steps, "
         "the state left at the end of the last completed one). A request that would take more than a year "
         "at 1e9 spring and particle updates a second is refused (csb.ParameterError, with the estimate).")
      .def_property_readonly("force_evaluations", &ForceStepper::force_evaluations,
           "Evaluations of the spring network's forces since construction: one per sub-step (velocity Verlet "
           "reuses the end of a sub-step's forces at the start of the next, unless damping or drag make them "
           "depend on the velocity: then two).");

  m.def("benchmark_dispatch", [](const Model& model, py::handle positions, IntArg sweeps_arg, IntArg repeats_arg) {
    const int sweeps = in_range<int>(sweeps_arg, "sweeps", 1, kMaxIndex), repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    const Positions x = to_positions(positions, "positions");
    DispatchTiming t;
    {
      py::gil_scoped_release release;
      t = benchmark_dispatch(model, x, sweeps, repeats);
    }
    py::dict d;
    d["projections"] = t.projections;
    d["batched_ns"] = t.batched_ns;
    d["virtual_ns"] = t.virtual_ns;
    d["identical"] = t.identical;
    return d;
  }, py::arg("model"), py::arg("positions"), py::arg("sweeps"), py::arg("repeats"),
     "Gauss-Seidel sweeps through the batched kernels and through one virtual Constraint object per constraint: "
     "ns per projection of each repeat, and whether the results agree bit for bit.");

  m.def("colour_constraints", [](py::array_t<Index, py::array::c_style | py::array::forcecast> particles,
                                 IntArg num_particles_arg, IntArg min_colour_size_arg) {
    const Index num_particles = index_arg(num_particles_arg, "num_particles");
    const Index min_colour_size = index_arg(min_colour_size_arg, "min_colour_size");
    if (particles.ndim() != 2 || particles.shape(1) < 1)
      throw InvalidArgument("particles must have shape (M, k), k >= 1");
    for (py::ssize_t e = 0; e < particles.size(); ++e)
      if (particles.data()[e] < 0 || particles.data()[e] >= num_particles)
        throw InvalidArgument("particle index " + std::to_string(particles.data()[e]) + " out of range");
    const Colouring c = colour_constraints(particles.data(), static_cast<int>(particles.shape(1)),
                                           static_cast<Index>(particles.shape(0)), num_particles, min_colour_size);
    py::dict d;
    d["order"] = py::array_t<Index>(static_cast<py::ssize_t>(c.order.size()), c.order.data());
    d["colour_offsets"] = py::array_t<Index>(static_cast<py::ssize_t>(c.colour_offsets.size()), c.colour_offsets.data());
    d["serial"] = serial_flags(c);
    return d;
  }, py::arg("particles"), py::arg("num_particles"), py::arg("min_colour_size") = kMinColourSize,
     "The greedy colouring a Model gives a batch whose constraint c has particles[c] (see Model.colouring).");
  m.attr("MAX_COLOURS") = kMaxColours;
  // The largest value of an integer parameter: an index or count (Index), the stepper's sub-steps,
  // iterations and threads.
  m.attr("MAX_INDEX") = kMaxIndex;
  m.attr("MAX_SUBSTEPS") = kMaxSubsteps;
  m.attr("MAX_ITERATIONS") = kMaxIterations;
  m.attr("MAX_THREADS") = kMaxThreads;
  m.attr("MIN_COLOUR_SIZE") = kMinColourSize;
  m.attr("MIN_TASK_COLOUR_SIZE") = kMinTaskColourSize;

  m.def("benchmark_plain_distance", [](const Model& model, py::handle positions, IntArg sweeps_arg, IntArg repeats_arg) {
    const int sweeps = in_range<int>(sweeps_arg, "sweeps", 1, kMaxIndex), repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    const Positions x = to_positions(positions, "positions");
    std::vector<double> ns;
    {
      py::gil_scoped_release release;
      ns = benchmark_plain_distance(model, x, sweeps, repeats);
    }
    return ns;
  }, py::arg("model"), py::arg("positions"), py::arg("sweeps"), py::arg("repeats"),
     "The baseline the coloured sweep is measured against: a plain sequential loop over the model's distance constraints in build order, in "
     "double precision (Müller's projection, stiffness 1), one thread; ns per projection of each repeat.");
  m.def("benchmark_jacobian", [](const SpringNetwork& net, const State& state, IntArg repeats_arg) {
    const int repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    std::vector<double> y(net.size()), values(net.jacobian_row_indices().size());
    net.pack(state, y.data());
    std::vector<double> ms;
    py::gil_scoped_release release;
    for (int r = 0; r < repeats; ++r) {
      const auto t0 = std::chrono::steady_clock::now();
      net.jacobian(y.data(), values.data());
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    return ms;
  }, py::arg("network"), py::arg("state"), py::arg("repeats"),
     "ms per assembly of the reference's sparse Jacobian (the values into its fixed CSC pattern), per repeat.");

  m.def("corrected_stiffness", [](double k, IntArg iterations) {
    return corrected_stiffness(k, in_range<int>(iterations, "iterations", 1, kMaxIterations));
  }, py::arg("stiffness"), py::arg("iterations"),
        "1 - (1 - k)^(1/iterations), Müller 2007 §3.3.");

}

}  // namespace csb::python
