// csb._core: State, Model and ModelBuilder.
#include "bindings.hpp"

#include "csb/constraints/families.hpp"
#include "csb/constraints/tether.hpp"

namespace csb::python {

namespace {

// A constraint family's batch as read-only views: particles (M, arity), one (M,) array per
// parameter, stiffness and compliance.
py::dict family_views(py::object self, const FamilyBatch* b, const FamilyInfo& info) {
  const py::ssize_t m = b ? b->size() : 0;
  py::dict d;
  if (!b) {
    d["particles"] = py::array_t<Index>({m, py::ssize_t(info.arity)});
    for (const std::string& name : info.param_names) d[name.c_str()] = py::array_t<Real>(m);
    d["stiffness"] = py::array_t<Real>(m);
    d["compliance"] = py::array_t<Real>(m);
    return d;
  }
  d["particles"] = view(b->particle_data(), {m, py::ssize_t(info.arity)}, self, false);
  const py::ssize_t np = info.num_params();
  for (py::ssize_t k = 0; k < np; ++k) {
    py::array a(py::dtype::of<Real>(), {m}, {static_cast<py::ssize_t>(sizeof(Real)) * np}, b->param_data() + k, self);
    a.attr("setflags")(py::arg("write") = false);
    d[info.param_names[static_cast<std::size_t>(k)].c_str()] = a;
  }
  d["stiffness"] = view(b->stiffness.data(), {m}, self, false);
  d["compliance"] = view(b->compliance.data(), {m}, self, false);
  return d;
}

std::string family_doc(const FamilyInfo& info) {
  std::string doc = info.name + " batch: particles (M, " + std::to_string(info.arity) + ")";
  for (int k = 0; k < info.num_params(); ++k) doc += ", " + info.param_names[k] + " (" + info.param_units[k] + ")";
  return doc + ", stiffness, compliance (" + info.compliance_unit + ")" +
         (info.unilateral ? "; unilateral: C <= 0 is satisfied" : "") + ". A constraint family (constraints/family.hpp).";
}

TetherMode parse_tether_mode(const std::string& s) {
  if (s == "euclidean") return TetherMode::Euclidean;
  if (s == "geodesic") return TetherMode::Geodesic;
  throw InvalidArgument("add_tethers: mode must be 'euclidean' or 'geodesic', got '" + s + "'");
}

}  // namespace

void bind_model(py::module_& m) {
  // ---------------------------------------------------------------- model
  py::class_<State, std::shared_ptr<State>>(m, "State", "Positions (m), velocities (m/s) and time (s) of every particle.")
      .def_property("x", [](py::object self) {
        State& s = self.cast<State&>();
        return view(s.x.data(), {s.x.cols(), 3}, self, true);
      }, [](State& s, py::handle value) {
        Positions x = to_positions(value, "State.x");
        if (x.cols() != s.x.cols()) throw InvalidArgument("State.x must have shape (" + std::to_string(s.x.cols()) + ", 3)");
        s.x = x;
      }, "(N, 3) positions, m: a writable view, no copy")
      .def_property("v", [](py::object self) {
        State& s = self.cast<State&>();
        return view(s.v.data(), {s.v.cols(), 3}, self, true);
      }, [](State& s, py::handle value) {
        Positions v = to_positions(value, "State.v");
        if (v.cols() != s.v.cols()) throw InvalidArgument("State.v must have shape (" + std::to_string(s.v.cols()) + ", 3)");
        s.v = v;
      }, "(N, 3) velocities, m/s: a writable view, no copy")
      .def_readwrite("t", &State::t, "time, s")
      .def_property("step", [](const State& s) { return s.step; },
                    [](State& s, IntArg step) { s.step = in_range<std::int64_t>(step, "State.step", 0, kMaxInt64); },
                    "number of completed steps")
      .def_property_readonly("num_particles", [](const State& s) { return s.x.cols(); })
      .def("copy", [](const State& s) { return std::make_shared<State>(s); }, "A deep copy (a checkpoint).")
      .def("__repr__", [](const State& s) {
        std::ostringstream o;
        o << "<csb.State " << s.x.cols() << " particles, t = " << s.t << " s, step " << s.step << ">";
        return o.str();
      });

  py::class_<Model, std::shared_ptr<Model>> model_class(m, "Model",
      "Immutable: rest positions, masses, and one batch per constraint type. Arrays are read-only views.");
  model_class
      .def_property_readonly("num_particles", &Model::num_particles)
      .def_property_readonly("num_constraints", &Model::num_constraints)
      .def_readonly("group_names", &Model::group_names)
      .def_property_readonly("rest_positions", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.rest_positions.data(), {s.num_particles(), 3}, self, false);
      }, "(N, 3) rest positions, m")
      .def_property_readonly("mass", particle_array(&Model::mass), "(N,) masses, kg (kept for pinned particles)")
      .def_property_readonly("inv_mass", particle_array(&Model::inv_mass), "(N,) inverse masses, 1/kg; 0 for pinned particles")
      .def_property_readonly("group", particle_array(&Model::group), "(N,) group index of each particle")
      .def_property_readonly("triangles", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(reinterpret_cast<const Index*>(s.triangles.data()), {static_cast<py::ssize_t>(s.triangles.size()), 3}, self, false);
      }, "(T, 3) surface triangles (particle indices)")
      .def_property_readonly("distance", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.distance;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 2}, self, false);
        d["rest_length"] = view(b.rest_length.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        d["sense"] = view(b.sense.data(), {c}, self, false);
        return d;
      }, "distance batch: particles (M, 2), rest_length (m), stiffness, compliance (m/N), sense (0: ==, +1: >=, -1: <=)")
      .def("colouring", [](py::object self, const std::string& batch) {
        const Model& s = self.cast<const Model&>();
        const Colouring* c = batch == "distance" ? &s.distance.colours
                             : batch == "bending" ? &s.bending.colours
                             : batch == "volume" ? &s.volume.colours
                             : batch == "attachments" ? &s.attachments.colours : nullptr;
        if (!c) throw InvalidArgument("batch must be 'distance', 'bending', 'volume' or 'attachments', got '" + batch + "'");
        py::dict d;
        d["order"] = view(c->order.data(), {static_cast<py::ssize_t>(c->order.size())}, self, false);
        d["colour_offsets"] = view(c->colour_offsets.data(), {static_cast<py::ssize_t>(c->colour_offsets.size())}, self, false);
        d["serial"] = serial_flags(*c);
        d["group_colours"] = view(c->group_colours.data(), {static_cast<py::ssize_t>(c->group_colours.size())}, self, false);
        return d;
      }, py::arg("batch"),
         "The batch's graph colouring: order (constraint indices colour by colour), colour_offsets (colour k is "
         "order[offsets[k]:offsets[k+1]]), serial (per colour: its constraints may share particles and are "
         "projected in order), group_colours (group g owns colours group_colours[g]:group_colours[g+1]; with P = "
         "num_parts, groups 0..P-1 are the parts' interiors, P+i the interface of parts i and i+1, 2P-1 the rest)")
      .def_property_readonly("num_parts", [](const Model& s) { return s.num_parts; },
         "Parts of the particles (runs of indices or slabs along an axis) that group the colourings for the threads")
      .def_property_readonly("particle_parts", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.part.data(), {static_cast<py::ssize_t>(s.part.size())}, self, false);
      }, "The part of each particle (see num_parts)")
      .def_property_readonly("interface_phases", [](const Model& s) { return s.interface_phases; },
         "The interfaces between parts (i: parts i and i+1) in phases whose interfaces share no particle")
      .def_property_readonly("memory", [](const Model& s) {
        const ModelMemory r = model_memory(s);
        py::dict d;
        d["particles"] = r.particles;
        d["distance"] = r.distance;
        d["bending"] = r.bending;
        d["volume"] = r.volume;
        d["balloons"] = r.balloons;
        d["attachments"] = r.attachments;
        d["families"] = r.families;
        d["other"] = r.other;
        d["total"] = r.total();
        return d;
      }, "Bytes the model's arrays hold (from their capacities), per part. Not counted: what stepping adds "
         "(PbdStepper.workspace_bytes, about as much again under PBD and twice under XPBD, and 48 B a particle "
         "per State) and the peak of building, when the builder's arrays, the mesh and the model coexist (about "
         "5 x this total for a cloth). csb run reports the process's peak resident memory.")
      .def_property_readonly("bending", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.bending;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 4}, self, false);
        d["rest_angle"] = view(b.rest_angle.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "bending batch: particles (M, 4) = edge (a, b) and wings (c, d), rest_angle (rad), stiffness, compliance (1/(N m))")
      .def_property_readonly("volume", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.volume;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 4}, self, false);
        d["rest_volume"] = view(b.rest_volume.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "volume batch: particles (M, 4) of each tet, rest_volume (m³), stiffness, compliance (m⁶/J)")
      .def_property_readonly("balloons", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.balloons;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particle_offsets"] = view(b.particle_offsets.data(), {c + 1}, self, false);
        d["particles"] = view(b.particles.data(), {static_cast<py::ssize_t>(b.particles.size())}, self, false);
        d["triangle_offsets"] = view(b.triangle_offsets.data(), {c + 1}, self, false);
        d["triangles"] = view(reinterpret_cast<const Index*>(b.triangles.data()),
                              {static_cast<py::ssize_t>(b.triangles.size()), 3}, self, false);
        d["rest_volume"] = view(b.rest_volume.data(), {c}, self, false);
        d["pressure"] = view(b.pressure.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "balloon batch: balloon b moves particles[particle_offsets[b]:particle_offsets[b+1]] and has "
         "triangles[triangle_offsets[b]:triangle_offsets[b+1]] (indices into its own particle list); rest_volume "
         "(m³), pressure (k_pressure: target volume pressure x rest_volume), stiffness, compliance (m⁶/J)")
      .def_property_readonly("attachments", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.attachments;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particle"] = view(b.particle.data(), {c}, self, false);
        d["target"] = view(b.target.data(), {c, 3}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "attachment batch: particle (M,), target (M, 3) m, stiffness, compliance (m/N)")
      .def_property_readonly("thickness", particle_array(&Model::thickness),
                             "(N,) collision radius of each particle against the colliders, m")
      .def_property_readonly("self_collision_thickness", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.self_collision_thickness.data(), {s.num_groups()}, self, false);
      }, "(G,) self-collision thickness h of each group, m (0: off)")
      .def_property_readonly("colliders", [](const Model& s) {
        py::list out;
        for (const Collider& c : s.colliders) {
          py::dict d;
          d["kind"] = kind_name(c.kind);
          d["name"] = c.name;
          d["friction_static"] = c.material.friction_static;
          d["friction_kinetic"] = c.material.friction_kinetic;
          d["restitution"] = c.material.restitution;
          switch (c.kind) {
            case ColliderKind::Plane:
              d["point"] = vec3_array(c.point);
              d["normal"] = vec3_array(c.normal);
              break;
            case ColliderKind::Sphere:
              d["center"] = vec3_array(c.center);
              d["radius"] = c.radius;
              break;
            case ColliderKind::Capsule:
              d["a"] = vec3_array(c.a);
              d["b"] = vec3_array(c.b);
              d["radius"] = c.radius;
              break;
            case ColliderKind::Box: {
              d["center"] = vec3_array(c.center);
              d["half_extents"] = vec3_array(c.half_extents);
              py::array_t<double> r({3, 3});
              for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) r.mutable_at(i, j) = c.rotation(i, j);
              d["rotation"] = r;
              break;
            }
            case ColliderKind::Mesh: {
              const auto& m = *c.mesh;
              py::array_t<double> v({static_cast<py::ssize_t>(m.vertices.cols()), py::ssize_t(3)});
              if (m.vertices.cols()) std::memcpy(v.mutable_data(), m.vertices.data(), sizeof(double) * m.vertices.size());
              d["vertices"] = v;
              d["triangles"] = index_rows(m.triangles);
              break;
            }
          }
          out.append(d);
        }
        return out;
      }, "The static colliders, one dict each (copies): kind, name, material (friction_static, friction_kinetic, "
         "restitution) and the geometry of its kind, in m.")
      .def("initial_state", [](const Model& s) { return std::make_shared<State>(s.initial_state()); },
           "A new State at the rest positions with zero velocities and t = 0.")
      .def_property_readonly("families", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        py::dict d;
        for (const FamilyInfo* info : families()) d[info->name.c_str()] = family_views(self, s.family(info->name), *info);
        return d;
      }, "Every constraint family's batch by name (see each family's own property, e.g. tethers)")
      .def("evaluate_family", [](const Model& s, const std::string& name, py::handle x_arg) {
        family_index(name);  // an unknown name: the error lists the known ones
        const FamilyBatch* b = s.family(name);
        const Positions x = to_positions(x_arg, "x");
        if (x.cols() != s.num_particles())
          throw InvalidArgument("x must have shape (" + std::to_string(s.num_particles()) + ", 3)");
        const FamilyInfo& info = *families()[family_index(name)];
        const py::ssize_t mc = b ? b->size() : 0, a = info.arity;
        py::array_t<Real> c(mc), grad({mc, a, py::ssize_t(3)}), forces({py::ssize_t(s.num_particles()), py::ssize_t(3)}),
            jac({mc, a, a, py::ssize_t(3), py::ssize_t(3)});
        std::fill(forces.mutable_data(), forces.mutable_data() + forces.size(), 0.0);
        py::dict d;
        d["energy"] = b ? b->energy(x.data()) : 0.0;
        if (b && mc > 0) {
          b->evaluate(x.data(), c.mutable_data(), grad.mutable_data());
          b->add_forces(x.data(), forces.mutable_data());
          b->stiffness_blocks(x.data(), jac.mutable_data());
        }
        d["C"] = c;
        d["grad"] = grad;
        d["forces"] = forces;
        d["jacobian"] = jac;
        return d;
      }, py::arg("family"), py::arg("x"),
         "A constraint family at positions x (N, 3) m, as the references see it: C (M,), grad (M, arity, 3) = ∂C/∂x, "
         "energy = Σ C₊²/(2α) J (C₊ = max(C, 0) for a unilateral family), forces (N, 3) = -∂energy/∂x N, jacobian "
         "(M, arity, arity, 3, 3): per constraint the blocks ∂f_i/∂x_j N/m (the Gauss-Newton term plus the "
         "curvature term where the family gives its Hessian). Hard constraints (α = 0) have no potential.")
      .def("__repr__", [](const Model& s) {
        std::string families;
        for (const auto& f : s.families)
          if (f->size() > 0) families += ", " + std::to_string(f->size()) + " " + f->info().name;
        return "<csb.Model " + std::to_string(s.num_particles()) + " particles, " + std::to_string(s.distance.size()) +
               " distance, " + std::to_string(s.bending.size()) + " bending, " + std::to_string(s.volume.size()) +
               " volume, " + std::to_string(s.balloons.size()) + " balloon, " + std::to_string(s.attachments.size()) +
               " attachment constraints" + families + ">";
      });
  static std::vector<std::string> family_docs;  // the docstrings outlive the module's set-up
  for (const FamilyInfo* info : families()) family_docs.push_back(family_doc(*info));
  for (std::size_t f = 0; f < families().size(); ++f) {
    const FamilyInfo* info = families()[f];
    model_class.def_property_readonly(info->name.c_str(), [info](py::object self) {
      return family_views(self, self.cast<const Model&>().family(info->name), *info);
    }, family_docs[f].c_str());
  }

  py::class_<ModelBuilder>(m, "ModelBuilder", "Collects particles and constraints; build() returns the immutable Model.")
      .def(py::init<>())
      .def("add_group", &ModelBuilder::add_group, py::arg("name"), "Adds a particle group; returns its index.")
      .def("add_particle", [](ModelBuilder& b, py::handle x, double mass, IntArg group) {
        return b.add_particle(to_vec3(x, "x"), mass, index_arg(group, "add_particle: group"));
      }, py::arg("x"), py::arg("mass"), py::arg("group"), "One particle at x (m) of mass (kg) in a group; returns its index.")
      .def("_add_mesh", [](ModelBuilder& b, const Mesh& mesh, IntArg group, py::object mass, py::object density,
                           py::object particle_mass, std::optional<double> stretch_stiffness,
                           std::optional<double> bending_stiffness, double stretch_compliance,
                           double bending_compliance, double thickness) {
        MeshOptions o;
        o.thickness = thickness;
        o.group = index_arg(group, "add_mesh: group", -1);
        o.mass = mass_spec(mesh.name, mass, density, particle_mass, "kg/m^2");
        o.stretch_stiffness = stretch_stiffness;
        o.bending_stiffness = bending_stiffness;
        o.stretch_compliance = stretch_compliance;
        o.bending_compliance = bending_compliance;
        return instance_dict(b.add_mesh(mesh, o));
      }, py::arg("mesh"), py::arg("group") = -1, py::arg("mass") = py::none(), py::arg("density") = py::none(),
         py::arg("particle_mass") = py::none(), py::arg("stretch_stiffness") = 1.0,
         py::arg("bending_stiffness") = py::none(), py::arg("stretch_compliance") = 0.0,
         py::arg("bending_compliance") = 0.0, py::arg("thickness") = 0.0)
      .def("add_distance", [](ModelBuilder& b, IntArg i, IntArg j, double stiffness, std::optional<double> rest_length,
                              const std::string& sense, double compliance) {
        const Index pi = index_arg(i, "add_distance: i"), pj = index_arg(j, "add_distance: j");
        return b.add_distance(pi, pj, stiffness, rest_length ? *rest_length : -1.0, parse_sense(sense), compliance);
      }, py::arg("i"), py::arg("j"), py::arg("stiffness") = 1.0, py::arg("rest_length") = py::none(),
         py::arg("sense") = "==", py::arg("compliance") = 0.0,
         "Distance constraint: PBD stiffness in [0, 1], compliance in m/N (0: hard); rest_length in m, default the "
         "current distance; sense '==', '>=' (at least) or '<=' (at most, a tether). Returns its index.")
      .def("add_bending", [](ModelBuilder& b, IntArg a, IntArg b_, IntArg c, IntArg d, double stiffness,
                             std::optional<double> rest_angle, double compliance) {
        const Index pa = index_arg(a, "add_bending: a"), pb = index_arg(b_, "add_bending: b");
        const Index pc = index_arg(c, "add_bending: c"), pd = index_arg(d, "add_bending: d");
        return b.add_bending(pa, pb, pc, pd, stiffness, rest_angle, compliance);
      }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"),
           py::arg("stiffness"), py::arg("rest_angle") = py::none(), py::arg("compliance") = 0.0,
           "Dihedral bending across edge (a, b) with wings c, d: PBD stiffness in [0, 1], rest_angle in rad "
           "(default the current angle), compliance in 1/(N m) (0: hard).")
      .def("_add_tet_mesh", [](ModelBuilder& b, const TetMesh& mesh, IntArg group, py::object mass, py::object density,
                               py::object particle_mass, std::optional<double> stretch_stiffness,
                               double stretch_compliance, std::optional<double> volume_stiffness,
                               double volume_compliance) {
        TetMeshOptions o;
        o.group = index_arg(group, "add_tet_mesh: group", -1);
        o.mass = mass_spec(mesh.name, mass, density, particle_mass, "kg/m^3");
        o.stretch_stiffness = stretch_stiffness;
        o.stretch_compliance = stretch_compliance;
        o.volume_stiffness = volume_stiffness;
        o.volume_compliance = volume_compliance;
        return instance_dict(b.add_tet_mesh(mesh, o));
      }, py::arg("mesh"), py::arg("group") = -1, py::arg("mass") = py::none(), py::arg("density") = py::none(),
         py::arg("particle_mass") = py::none(), py::arg("stretch_stiffness") = 1.0, py::arg("stretch_compliance") = 0.0,
         py::arg("volume_stiffness") = 1.0, py::arg("volume_compliance") = 0.0)
      .def("add_tetrahedron", [](ModelBuilder& b, IntArg a, IntArg b_, IntArg c, IntArg d, double stiffness,
                                 double compliance, std::optional<double> rest_volume) {
        const Index pa = index_arg(a, "add_tetrahedron: a"), pb = index_arg(b_, "add_tetrahedron: b");
        const Index pc = index_arg(c, "add_tetrahedron: c"), pd = index_arg(d, "add_tetrahedron: d");
        return b.add_tetrahedron(pa, pb, pc, pd, stiffness, compliance, rest_volume);
      }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"),
           py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0, py::arg("rest_volume") = py::none(),
           "Tetrahedral volume constraint C = V - V0: PBD stiffness in [0, 1], compliance in m⁶/J (0: hard), "
           "rest_volume in m³ (default the current signed volume, which must be > 0: d on the side of "
           "(b - a) x (c - a)). Returns its index.")
      .def("_add_balloon", [](ModelBuilder& b, py::handle triangles, double pressure, double stiffness,
                              double compliance) {
        return b.add_balloon(to_index_rows<3>(triangles, "balloon triangles"), pressure, stiffness, compliance);
      }, py::arg("triangles"), py::arg("pressure") = 1.0, py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0)
      .def("pin", [](ModelBuilder& b, IntArg i) { b.pin(index_arg(i, "pin: i")); }, py::arg("i"), "Fixes particle i (inverse mass 0).")
      .def("attach", [](ModelBuilder& b, IntArg i, py::handle target, double stiffness, double compliance) {
        return b.attach(index_arg(i, "attach: i"), to_vec3(target, "target"), stiffness, compliance);
      }, py::arg("i"), py::arg("target"), py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0,
         "Holds particle i at a world point (m): PBD stiffness in [0, 1], compliance in m/N (0: hard).")
      .def("add_constraint", [](ModelBuilder& b, const std::string& family, const std::vector<IntArg>& particles,
                                std::vector<double> params, double stiffness, double compliance) {
        std::vector<Index> ids;
        for (const IntArg& i : particles) ids.push_back(index_arg(i, "add_constraint: particles"));
        return b.add_constraint(family, ids, params, stiffness, compliance);
      }, py::arg("family"), py::arg("particles"), py::arg("params"), py::arg("stiffness") = 1.0,
         py::arg("compliance") = 0.0,
         "A constraint of a constraint family (Model.families): its particles (the family's arity), its parameters "
         "(the family's, in order and in their units), PBD stiffness in [0, 1], compliance in the family's unit "
         "(0: hard). Returns its index in the family's batch.")
      .def("add_tethers", [](ModelBuilder& b, const std::string& mode, double max_stretch, double stiffness,
                             double compliance, IntArg anchors) {
        TetherOptions o;
        o.mode = parse_tether_mode(mode);
        o.max_stretch = max_stretch;
        o.stiffness = stiffness;
        o.compliance = compliance;
        o.anchors = in_range<Index>(anchors, "add_tethers: anchors", 1, kMaxIndex);
        return add_tethers(b, o);
      }, py::kw_only(), py::arg("mode") = "geodesic", py::arg("max_stretch") = 1.0, py::arg("stiffness") = 1.0,
         py::arg("compliance") = 0.0, py::arg("anchors") = 1,
         "Long range attachments (Kim, Chentanez and Müller 2012): tethers every free particle to its `anchors` "
         "nearest pinned particles (among those its distance constraints reach) with the unilateral constraint "
         "|x_i - x_a| <= L, L = max_stretch (>= 1) x the rest distance: 'euclidean' (the straight line in the rest "
         "positions) or 'geodesic' (the shortest path through the distance constraints, by rest length). Pin and "
         "add the meshes first. PBD stiffness in [0, 1], compliance in m/N (0: hard). Returns the tethers added; "
         "they are in Model.tethers.")
      .def("position", [](const ModelBuilder& b, IntArg particle) {
        const Index i = index_arg(particle, "position: i");
        if (i < 0 || i >= b.num_particles()) throw InvalidArgument("particle index " + std::to_string(i) + " is out of range");
        return vec3_array(b.position(i));
      }, py::arg("i"))
      .def("add_plane", [](ModelBuilder& b, py::handle point, py::handle normal, double mus, double muk, double e,
                           const std::string& name) {
        return b.add_plane(to_vec3(point, "point"), to_vec3(normal, "normal"), material(mus, muk, e), name);
      }, py::kw_only(), py::arg("point") = std::vector<double>{0, 0, 0}, py::arg("normal") = std::vector<double>{0, 1, 0},
         py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0,
         py::arg("name") = "",
         "Static half-space collider: solid where (x - point)·normal < 0. point in m; normal any non-zero vector "
         "towards the free side. friction_static μs >= friction_kinetic μk >= 0 (Coulomb), restitution e in [0, 1]. "
         "Returns the collider's index.")
      .def("add_sphere", [](ModelBuilder& b, py::handle center, double radius, double mus, double muk, double e,
                            const std::string& name) {
        return b.add_sphere(to_vec3(center, "center"), radius, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("center"), py::arg("radius"), py::arg("friction_static") = 0.0,
         py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static sphere collider: center in m, radius > 0 m; material as add_plane.")
      .def("add_capsule", [](ModelBuilder& b, py::handle a, py::handle end, double radius, double mus, double muk,
                             double e, const std::string& name) {
        return b.add_capsule(to_vec3(a, "a"), to_vec3(end, "b"), radius, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("a"), py::arg("b"), py::arg("radius"), py::arg("friction_static") = 0.0,
         py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static capsule collider: the points within radius (> 0 m) of the segment a-b (m); material as add_plane.")
      .def("add_box", [](ModelBuilder& b, py::handle center, py::handle half_extents, py::handle rotation, double mus,
                         double muk, double e, const std::string& name) {
        const Mat3 r = rotation.is_none() ? Mat3::Identity() : to_mat3(rotation, "rotation");
        return b.add_box(to_vec3(center, "center"), to_vec3(half_extents, "half_extents"), r, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("center"), py::arg("half_extents"), py::arg("rotation") = py::none(),
         py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0,
         py::arg("name") = "",
         "Static oriented box collider: center in m, half_extents > 0 m along the box's axes, rotation a 3 x 3 "
         "rotation matrix whose columns are those axes in the world (default identity); material as add_plane.")
      .def("add_collider_mesh", [](ModelBuilder& b, const Mesh& mesh, double mus, double muk, double e,
                                   const std::string& name) {
        return b.add_collider_mesh(mesh, material(mus, muk, e), name);
      }, py::arg("mesh"), py::kw_only(), py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0,
         py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static triangle-mesh collider (any mesh csb.load_mesh reads), a two-sided sheet: a particle keeps the side "
         "it is on. Material as add_plane.")
      .def("set_thickness", [](ModelBuilder& b, IntArg group, double thickness) {
        b.set_thickness(index_arg(group, "set_thickness: group"), thickness);
      }, py::arg("group"), py::arg("thickness"),
           "Collision radius (m, >= 0) of every particle of a group against the colliders.")
      .def("enable_self_collision", [](ModelBuilder& b, IntArg group, double thickness) {
        b.enable_self_collision(index_arg(group, "enable_self_collision: group"), thickness);
      }, py::arg("group"), py::arg("thickness"),
           "Point-triangle self-collision of a group's cloth (Müller 2007 §4.4) with thickness h > 0 m; keep h "
           "below the cloth's edge length.")
      .def_property_readonly("num_colliders", &ModelBuilder::num_colliders)
      .def_property_readonly("num_particles", &ModelBuilder::num_particles)
      .def("build", [](const ModelBuilder& b) { return std::const_pointer_cast<Model>(b.build()); });

}

}  // namespace csb::python
