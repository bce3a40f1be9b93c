// jolt_cloth: csb's benchmark cloth as one Jolt Physics soft body (XPBD), timed per frame.
//
// A benchmark peer, built against the user's own Jolt tree (see CMakeLists.txt); csb does not
// ship or vendor Jolt. scripts/jolt_cloth.py writes the cloth file, runs this program and checks
// its output against csb's counts and csb.bench.peers.check_cloth.
//
// The body is built from csb's arrays only:
//   csb particle i (position, inverse mass w_i, w = 0 pinned) -> Jolt Vertex i (mInvMass = w_i)
//   csb distance pair (i, j), rest length L, compliance 0     -> Jolt Edge (i, j), mRestLength = L
//   csb bending quadruple (a, b, c, d), compliance alpha      -> Jolt DihedralBend (a, b, c, d)
//     ((a, b) the shared edge, c and d the opposite vertices: the same order as Jolt's x0, x1 | x2, x3)
// No faces are given and CreateConstraints (which derives edges and bends from faces) is never
// called; Optimize() only reorders the constraints into groups that can run in parallel, and the
// program checks, through Optimize's remap tables, that every constraint came through unchanged.
//
// Time stepping. In Jolt a soft body's "iteration" is a whole XPBD sub-step
// (SoftBodyMotionProperties: InitializeUpdateContext sets h = dt / mNumIterations, and each
// iteration integrates the velocities and positions over h (gravity, linear damping), projects
// every constraint once with alpha / h^2, then sets v = (x - x_prev) / h). There is no separate
// inner iteration count, and no Lagrange multiplier is carried between projections, so
// mNumIterations = S gives exactly csb's S sub-steps x 1 iteration; csb's 1 x K case has no Jolt
// equivalent.
//
// Two ways to step (--mode):
//   system: the body is added to a PhysicsSystem that holds nothing else; PhysicsSystem::Update
//           (one collision step per frame) runs it through Jolt's job system, which is how Jolt
//           users run soft bodies and the only multi-threaded path: the workers take the
//           parallel constraint groups of each sub-step. --threads T = T - 1 worker threads
//           plus the calling thread, which runs jobs while it waits.
//   custom: SoftBodyMotionProperties::CustomUpdate steps the body without adding it to the
//           system; it runs the same ParallelUpdate state machine on the calling thread only
//           (single-threaded by construction).
//
// Output: one JSON line on stdout.
//
// --serve: build the body once, then answer commands on stdin, one line in, one JSON line out
// (flushed), for csb.bench.peers' JoltSide, which times the frames itself so that every side of
// `csb bench --peers` is timed the same way:
//   info            the counts, settings, version and SIMD level (the fields of the output above
//                   that are not timings)
//   reset           back to the rest positions, velocities zero
//   frames K        step K frames; answers when they are done
//   positions PATH  write the world positions to PATH (float64 [N][3])
//   quit            answer and end (end of input ends it too)
// An unknown or malformed command is answered with {"error": "..."}; the body is unchanged.
//
// Cloth file (binary, little endian, written by scripts/jolt_cloth.py):
//   char[8] "CSBCLTH1"; int64 N, E, B;
//   float64 positions[N][3] (m); float64 inv_mass[N] (1/kg);
//   int64 distance[E][2]; float64 rest_length[E] (m); float64 stretch_compliance (m/N);
//   int64 bending[B][4]; float64 bending_compliance (1/(N m))
// Positions file (--positions, --hold-positions): float64 [N][3], world frame, m.

#include <Jolt/Jolt.h>

#include <Jolt/Core/Factory.h>
#include <Jolt/Core/JobSystemThreadPool.h>
#include <Jolt/Core/TempAllocator.h>
#include <Jolt/Physics/Body/BodyInterface.h>
#include <Jolt/Physics/Collision/BroadPhase/BroadPhaseLayer.h>
#include <Jolt/Physics/PhysicsSettings.h>
#include <Jolt/Physics/PhysicsSystem.h>
#include <Jolt/Physics/SoftBody/SoftBodyCreationSettings.h>
#include <Jolt/Physics/SoftBody/SoftBodyMotionProperties.h>
#include <Jolt/Physics/SoftBody/SoftBodySharedSettings.h>
#include <Jolt/RegisterTypes.h>

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

using namespace JPH;

namespace {

[[noreturn]] void fail(const std::string &message) {
  std::fprintf(stderr, "jolt_cloth: %s\n", message.c_str());
  std::exit(2);
}

// ---------------------------------------------------------------------------------------------
// The cloth as csb gives it

struct Cloth {
  std::vector<double> x;        // N x 3, m
  std::vector<double> w;        // N, inverse mass 1/kg (0 = pinned)
  std::vector<int64_t> dist;    // E x 2
  std::vector<double> rest;     // E, m
  double stretch_compliance = 0; // m/N
  std::vector<int64_t> bend;    // B x 4: (a, b) shared edge, c, d opposite vertices
  double bending_compliance = 0; // 1/(N m)
  size_t n() const { return w.size(); }
  size_t e() const { return rest.size(); }
  size_t b() const { return bend.size() / 4; }
};

template <class T> void read(std::FILE *f, T *out, size_t count) {
  if (std::fread(out, sizeof(T), count, f) != count) fail("cloth file too short");
}

Cloth read_cloth(const char *path) {
  std::FILE *f = std::fopen(path, "rb");
  if (!f) fail(std::string("cannot open ") + path);
  char magic[8];
  read(f, magic, 8);
  if (std::memcmp(magic, "CSBCLTH1", 8) != 0) fail("not a CSBCLTH1 cloth file");
  int64_t n, e, b;
  read(f, &n, 1), read(f, &e, 1), read(f, &b, 1);
  Cloth c;
  c.x.resize(3 * n), c.w.resize(n), c.dist.resize(2 * e), c.rest.resize(e), c.bend.resize(4 * b);
  read(f, c.x.data(), c.x.size());
  read(f, c.w.data(), c.w.size());
  read(f, c.dist.data(), c.dist.size());
  read(f, c.rest.data(), c.rest.size());
  read(f, &c.stretch_compliance, 1);
  read(f, c.bend.data(), c.bend.size());
  read(f, &c.bending_compliance, 1);
  std::fclose(f);
  for (int64_t i : c.dist) if (i < 0 || i >= n) fail("distance index out of range");
  for (int64_t i : c.bend) if (i < 0 || i >= n) fail("bending index out of range");
  return c;
}

// ---------------------------------------------------------------------------------------------
// Layers: one object layer whose bodies collide with nothing (csb's cloth has no contacts; Jolt
// soft bodies have no self-collision)

constexpr ObjectLayer kClothLayer = 0;

class OneBroadPhaseLayer final : public BroadPhaseLayerInterface {
public:
  uint GetNumBroadPhaseLayers() const override { return 1; }
  BroadPhaseLayer GetBroadPhaseLayer(ObjectLayer) const override { return BroadPhaseLayer(0); }
#if defined(JPH_EXTERNAL_PROFILE) || defined(JPH_PROFILE_ENABLED)
  const char *GetBroadPhaseLayerName(BroadPhaseLayer) const override { return "CLOTH"; }
#endif
};

class NoObjectVsBroadPhase final : public ObjectVsBroadPhaseLayerFilter {
public:
  bool ShouldCollide(ObjectLayer, BroadPhaseLayer) const override { return false; }
};

class NoObjectPairs final : public ObjectLayerPairFilter {
public:
  bool ShouldCollide(ObjectLayer, ObjectLayer) const override { return false; }
};

// ---------------------------------------------------------------------------------------------
// Options

struct Options {
  const char *cloth = nullptr;
  std::string mode = "system";
  int threads = 1;
  int substeps = 10;
  double dt = 1.0 / 60.0; // s per frame
  int frames = 5, warmup = 5, rounds = 7, max_rounds = 2000, hold = 0;
  double min_time = 1.0; // s of timed frames
  const char *positions = nullptr, *hold_positions = nullptr;
  bool serve = false;
};

Options parse(int argc, char **argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&]() -> const char * {
      if (i + 1 >= argc) fail("missing value after " + a);
      return argv[++i];
    };
    if (a == "--mode") o.mode = value();
    else if (a == "--threads") o.threads = std::atoi(value());
    else if (a == "--substeps") o.substeps = std::atoi(value());
    else if (a == "--dt") o.dt = std::atof(value());
    else if (a == "--frames") o.frames = std::atoi(value());
    else if (a == "--warmup") o.warmup = std::atoi(value());
    else if (a == "--rounds") o.rounds = std::atoi(value());
    else if (a == "--max-rounds") o.max_rounds = std::atoi(value());
    else if (a == "--min-time") o.min_time = std::atof(value());
    else if (a == "--positions") o.positions = value();
    else if (a == "--hold") o.hold = std::atoi(value());
    else if (a == "--hold-positions") o.hold_positions = value();
    else if (a == "--serve") o.serve = true;
    else if (a[0] != '-' && !o.cloth) o.cloth = argv[i];
    else fail("unknown argument " + a);
  }
  if (!o.cloth)
    fail("usage: jolt_cloth CLOTH_FILE [--mode system|custom] [--threads T] [--substeps S] [--dt S]\n"
         "       [--frames F] [--warmup W] [--rounds R] [--min-time SEC] [--max-rounds M]\n"
         "       [--positions OUT] [--hold H] [--hold-positions OUT]\n"
         "       jolt_cloth CLOTH_FILE --serve [--mode system|custom] [--threads T] [--substeps S] [--dt S]");
  if (o.mode != "system" && o.mode != "custom") fail("--mode is system or custom");
  if (o.mode == "custom" && o.threads != 1) fail("--mode custom is single-threaded (CustomUpdate runs on the calling thread)");
  if (o.threads < 1 || o.substeps < 1 || o.frames < 1 || o.rounds < 1) fail("threads, substeps, frames, rounds must be >= 1");
  return o;
}

// ---------------------------------------------------------------------------------------------
// Jolt's shared settings from csb's arrays, and the check that Optimize kept them

Ref<SoftBodySharedSettings> build_settings(const Cloth &c, bool &identical, float &max_initial_angle) {
  Ref<SoftBodySharedSettings> s = new SoftBodySharedSettings;
  for (size_t i = 0; i < c.n(); ++i)
    s->mVertices.push_back(SoftBodySharedSettings::Vertex(
        Float3(float(c.x[3 * i]), float(c.x[3 * i + 1]), float(c.x[3 * i + 2])), Float3(0, 0, 0), float(c.w[i])));
  for (size_t k = 0; k < c.e(); ++k) {
    SoftBodySharedSettings::Edge edge(uint32(c.dist[2 * k]), uint32(c.dist[2 * k + 1]), float(c.stretch_compliance));
    edge.mRestLength = float(c.rest[k]); // csb's rest length, not recomputed by CalculateEdgeLengths
    s->mEdgeConstraints.push_back(edge);
  }
  for (size_t k = 0; k < c.b(); ++k) {
    const int64_t *q = &c.bend[4 * k];
    s->mDihedralBendConstraints.push_back(SoftBodySharedSettings::DihedralBend(
        uint32(q[0]), uint32(q[1]), uint32(q[2]), uint32(q[3]), float(c.bending_compliance)));
  }
  // Rest angle of each bend, from the rest positions (Jolt's convention: signed pi - dihedral
  // angle; 0 for csb's flat cloth, as csb's rest angle is the flat one too).
  s->CalculateBendConstraintConstants();
  max_initial_angle = 0;
  for (const auto &b : s->mDihedralBendConstraints) max_initial_angle = std::max(max_initial_angle, std::abs(b.mInitialAngle));

  // Reorder into parallel groups (required before simulation); remap[old] = new index
  SoftBodySharedSettings::OptimizationResults r;
  s->Optimize(r);

  identical = s->mVertices.size() == c.n() && s->mEdgeConstraints.size() == c.e() &&
              s->mDihedralBendConstraints.size() == c.b() && r.mEdgeRemap.size() == c.e() &&
              r.mDihedralBendRemap.size() == c.b() && s->mVolumeConstraints.empty() &&
              s->mSkinnedConstraints.empty() && s->mLRAConstraints.empty() &&
              s->mRodStretchShearConstraints.empty() && s->mRodBendTwistConstraints.empty() && s->mFaces.empty();
  for (size_t i = 0; identical && i < c.n(); ++i)
    identical = s->mVertices[i].mInvMass == float(c.w[i]);
  std::vector<char> seen(c.e(), 0);
  for (size_t k = 0; identical && k < c.e(); ++k) {
    uint j = r.mEdgeRemap[k];
    identical = j < c.e() && !seen[j];
    if (!identical) break;
    seen[j] = 1;
    const auto &e = s->mEdgeConstraints[j];
    identical = e.mVertex[0] == uint32(c.dist[2 * k]) && e.mVertex[1] == uint32(c.dist[2 * k + 1]) &&
                e.mRestLength == float(c.rest[k]) && e.mCompliance == float(c.stretch_compliance);
  }
  seen.assign(c.b(), 0);
  for (size_t k = 0; identical && k < c.b(); ++k) {
    uint j = r.mDihedralBendRemap[k];
    identical = j < c.b() && !seen[j];
    if (!identical) break;
    seen[j] = 1;
    const auto &b = s->mDihedralBendConstraints[j];
    for (int v = 0; v < 4; ++v) identical = identical && b.mVertex[v] == uint32(c.bend[4 * k + v]);
    identical = identical && b.mCompliance == float(c.bending_compliance);
  }
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

} // namespace

int main(int argc, char **argv) {
  const Options opt = parse(argc, argv);
  const Cloth cloth = read_cloth(opt.cloth);

  // Jolt's minimal start-up (as in its HelloWorld)
  RegisterDefaultAllocator();
  Factory::sInstance = new Factory();
  RegisterTypes();
  {
    TempAllocatorImpl temp_allocator(32 * 1024 * 1024);
    // T - 1 workers: the thread calling Update runs jobs too (GetMaxConcurrency = workers + 1)
    JobSystemThreadPool job_system(cMaxPhysicsJobs, cMaxPhysicsBarriers, opt.mode == "system" ? opt.threads - 1 : 0);

    OneBroadPhaseLayer bp_layers;
    NoObjectVsBroadPhase object_vs_bp;
    NoObjectPairs object_pairs;
    PhysicsSystem system;
    system.Init(/*max bodies*/ 16, /*body mutexes: default*/ 0, /*max body pairs*/ 64, /*max contacts*/ 64,
                bp_layers, object_vs_bp, object_pairs);
    system.SetGravity(Vec3(0.0f, -9.81f, 0.0f)); // m/s², csb's gravity (Jolt's default too)

    bool identical = false;
    float max_initial_angle = 0;
    Ref<SoftBodySharedSettings> shared = build_settings(cloth, identical, max_initial_angle);

    // The body at the origin with identity rotation: its local frame is csb's world frame.
    SoftBodyCreationSettings cs(shared, RVec3::sZero(), Quat::sIdentity(), kClothLayer);
    cs.mNumIterations = uint32(opt.substeps); // = XPBD sub-steps per frame (see the top of the file)
    cs.mLinearDamping = 0.0f;                 // csb has no damping (Jolt's default is 0.1 /s)
    cs.mPressure = 0.0f;                      // no pressure (the default; a cloth encloses no volume)
    cs.mGravityFactor = 1.0f;
    cs.mVertexRadius = 0.0f;                  // no collision radius (the default)
    cs.mAllowSleeping = false;                // csb's cloth never sleeps; a sleeping body is not stepped
    // mMaxLinearVelocity stays at Jolt's 500 m/s clamp: never reached here (free fall reaches ~1 m/s).
    // mUpdatePosition stays true (Jolt's default): after each frame the vertices are re-centred on
    // their bounding box and the body's position moves by the same amount; positions read back
    // below are world positions (body transform * local vertex).

    BodyInterface &bi = system.GetBodyInterface();
    Body *body = bi.CreateSoftBody(cs);
    if (!body) fail("CreateSoftBody failed");
    const BodyID id = body->GetID();
    if (opt.mode == "system") bi.AddBody(id, EActivation::Activate); // the only body in the system
    auto *mp = static_cast<SoftBodyMotionProperties *>(body->GetMotionProperties());

    // The state at rest, to restart every round from it
    const RVec3 p0 = body->GetPosition();
    std::vector<Vec3> x0;
    for (const SoftBodyVertex &v : mp->GetVertices()) x0.push_back(v.mPosition);
    auto reset = [&]() {
      Array<SoftBodyVertex> &verts = mp->GetVertices();
      for (size_t i = 0; i < verts.size(); ++i) {
        verts[i].mPosition = verts[i].mPreviousPosition = x0[i];
        verts[i].mVelocity = Vec3::sZero();
      }
      bi.SetPosition(id, p0, EActivation::DontActivate);
    };
    const float dt = float(opt.dt);
    auto frames = [&](int k) {
      for (int f = 0; f < k; ++f) {
        if (opt.mode == "system") {
          EPhysicsUpdateError err = system.Update(dt, 1, &temp_allocator, &job_system);
          if (err != EPhysicsUpdateError::None) fail("PhysicsSystem::Update reported an error");
        } else {
          mp->CustomUpdate(dt, *body, system);
        }
      }
    };
    auto world_positions = [&]() {
      RMat44 com = body->GetCenterOfMassTransform();
      std::vector<double> out;
      for (const SoftBodyVertex &v : mp->GetVertices()) {
        RVec3 p = com * v.mPosition;
        out.push_back(double(p.GetX())), out.push_back(double(p.GetY())), out.push_back(double(p.GetZ()));
      }
      return out;
    };
    // Sanity of the current positions: finite, pins unmoved (m), lowest y (m)
    auto sanity = [&](const std::vector<double> &x, char *buf, size_t size) {
      bool finite = true;
      double pin_moved = 0, lowest = INFINITY;
      for (size_t i = 0; i < cloth.n(); ++i) {
        for (int d = 0; d < 3; ++d) {
          finite = finite && std::isfinite(x[3 * i + d]);
          if (cloth.w[i] == 0) pin_moved = std::max(pin_moved, std::abs(x[3 * i + d] - cloth.x[3 * i + d]));
        }
        lowest = std::min(lowest, x[3 * i + 1]);
      }
      if (finite)
        std::snprintf(buf, size, "{\"finite\": true, \"pin_moved\": %.3g, \"lowest_y\": %.6g}", pin_moved, lowest);
      else
        std::snprintf(buf, size, "{\"finite\": false, \"pin_moved\": null, \"lowest_y\": null}");
    };
    auto write = [&](const char *path, const std::vector<double> &x) {
      std::FILE *f = std::fopen(path, "wb");
      bool ok = f && std::fwrite(x.data(), sizeof(double), x.size(), f) == x.size();
      if (f) ok = std::fclose(f) == 0 && ok;
      return ok;
    };

    // What the body is, read back from Jolt's objects (the body's settings, after Optimize): the
    // fields of every output but the timings, without the closing brace
#if defined(JPH_USE_AVX512)
    const char *simd = "avx512";
#elif defined(JPH_USE_AVX2)
    const char *simd = "avx2";
#else
    const char *simd = "sse/other";
#endif
    auto info = [&]() {
      const SoftBodySharedSettings *s = mp->GetSettings();
      char buf[2048];
      std::snprintf(
          buf, sizeof(buf),
          "{\"engine\": \"jolt\", \"jolt_version\": \"%d.%d.%d\", \"simd\": \"%s\", \"mode\": \"%s\", \"threads\": %d, "
          "\"particles\": %zu, \"edge_constraints\": %zu, \"bend_constraints\": %zu, \"other_constraints\": %zu, "
          "\"constraints_identical\": %s, \"bend_initial_angle_max\": %.3g, "
          "\"iterations\": %u, \"substeps_per_frame\": %u, \"iterations_per_substep\": 1, \"dt\": %.9g, \"substep_dt\": %.9g, "
          "\"linear_damping\": %g, \"gravity_y\": %g",
          JPH_VERSION_MAJOR, JPH_VERSION_MINOR, JPH_VERSION_PATCH, simd, opt.mode.c_str(),
          opt.mode == "system" ? job_system.GetMaxConcurrency() : 1, mp->GetVertices().size(),
          s->mEdgeConstraints.size(), s->mDihedralBendConstraints.size(),
          s->mVolumeConstraints.size() + s->mSkinnedConstraints.size() + s->mLRAConstraints.size() +
              s->mRodStretchShearConstraints.size() + s->mRodBendTwistConstraints.size(),
          identical ? "true" : "false", double(max_initial_angle), mp->GetNumIterations(), mp->GetNumIterations(),
          opt.dt, opt.dt / mp->GetNumIterations(), double(body->GetMotionProperties()->GetLinearDamping()),
          double(system.GetGravity().GetY()));
      return std::string(buf);
    };

    if (opt.serve) {
      // One line in, one line out. A cloth file path or a positions path may be long: lines of
      // up to 64 KiB.
      std::vector<char> line(1 << 16);
      auto answer = [](const std::string &json) {
        std::fputs(json.c_str(), stdout);
        std::fputc('\n', stdout);
        std::fflush(stdout);
      };
      reset();
      while (std::fgets(line.data(), int(line.size()), stdin)) {
        std::string cmd(line.data());
        while (!cmd.empty() && (cmd.back() == '\n' || cmd.back() == '\r')) cmd.pop_back();
        const size_t space = cmd.find(' ');
        const std::string word = cmd.substr(0, space), arg = space == std::string::npos ? "" : cmd.substr(space + 1);
        if (word == "info") {
          answer(info() + "}");
        } else if (word == "reset") {
          reset();
          answer("{\"reset\": true}");
        } else if (word == "frames") {
          char *rest = nullptr;
          long k = std::strtol(arg.c_str(), &rest, 10);
          if (arg.empty() || *rest != '\0' || k < 0) {
            answer("{\"error\": \"frames takes a count >= 0\"}");
            continue;
          }
          frames(int(k));
          answer("{\"frames\": " + std::to_string(k) + "}");
        } else if (word == "positions") {
          if (arg.empty()) {
            answer("{\"error\": \"positions takes a file path\"}");
            continue;
          }
          if (!write(arg.c_str(), world_positions())) {
            answer("{\"error\": \"cannot write the positions file\"}");
            continue;
          }
          answer("{\"positions\": " + std::to_string(cloth.n()) + "}");
        } else if (word == "quit") {
          answer("{\"quit\": true}");
          break;
        } else {
          answer("{\"error\": \"unknown command (info, reset, frames K, positions PATH, quit)\"}");
        }
      }
    } else {
      // Timing, as csb.bench.peers times a turn: warm-up frames, then rounds that each restart
      // from rest and time the same first `frames` frames; at least `rounds` rounds and
      // `min_time` seconds of timed frames, at most `max_rounds` rounds.
      using clock = std::chrono::steady_clock;
      reset();
      frames(opt.warmup);
      std::vector<double> ms;
      double timed = 0;
      // CPU seconds (all threads, user + system) over the timed rounds: cpu / wall near T when the
      // T threads all ran, near 1 when the workers found no free core (a shared machine)
      auto cpu_seconds = []() {
        rusage u;
        getrusage(RUSAGE_SELF, &u);
        return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
      };
      const double cpu0 = cpu_seconds();
      while (int(ms.size()) < opt.max_rounds && (int(ms.size()) < opt.rounds || timed < opt.min_time)) {
        reset();
        auto t0 = clock::now();
        frames(opt.frames);
        double s = std::chrono::duration<double>(clock::now() - t0).count();
        timed += s;
        ms.push_back(s * 1e3 / opt.frames);
      }
      const double cpu_per_wall = (cpu_seconds() - cpu0) / timed;
      char after[256], held[256] = "null";
      std::vector<double> x = world_positions(); // `frames` frames from rest
      sanity(x, after, sizeof(after));
      if (opt.positions && !write(opt.positions, x)) fail(std::string("cannot write ") + opt.positions);
      if (opt.hold > 0) { // longer: does the cloth hang, or diverge?
        reset();
        frames(opt.hold);
        std::vector<double> xh = world_positions();
        sanity(xh, held, sizeof(held));
        if (opt.hold_positions && !write(opt.hold_positions, xh))
          fail(std::string("cannot write ") + opt.hold_positions);
      }

      std::printf(
          "%s, \"frames\": %d, \"warmup\": %d, \"rounds\": %zu, \"ms_per_frame\": %.6g, \"ms_min\": %.6g, \"ms_max\": %.6g, "
          "\"cpu_per_wall\": %.3g, \"after_frames\": %s, \"hold_frames\": %d, \"after_hold\": %s}\n",
          info().c_str(), opt.frames, opt.warmup, ms.size(), median(ms), *std::min_element(ms.begin(), ms.end()),
          *std::max_element(ms.begin(), ms.end()), cpu_per_wall, after, opt.hold, held);
    }

    if (opt.mode == "system") bi.RemoveBody(id);
    bi.DestroyBody(id);
  }
  UnregisterTypes();
  delete Factory::sInstance;
  Factory::sInstance = nullptr;
  return 0;
}
