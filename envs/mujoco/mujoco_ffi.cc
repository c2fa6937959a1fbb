// The MuJoCo C backend as XLA FFI custom calls: a batch of envs stepped (or forwarded) by
// MuJoCo's threaded batch (mjBatch) inside the compiled program, with no Python in between.
//
// Built and loaded by envs/mujoco/mujoco_ffi_build.py; called by envs/mujoco/mujoco_ffi.py, whose
// docstring describes the operands and results. The physics state travels as the raw bits of
// float64 values (two uint32 words per number), exactly as on the pure_callback path
// (envs/mujoco/mujoco_backend.py), and a call computes what that path computes, with the same
// MuJoCo functions, so the two are bit-identical.
//
// A model is identified by a 64-bit key, an operand of the call (two uint32 words) that the
// Python side derives from the model's content; the HLO of a program is then the same in every
// process and the program can come from JAX's persistent compilation cache. The key is resolved
// in a registry that rl_jax_mujoco_register fills when an env is built.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <mujoco/mjbatch.h>
#include <mujoco/mjxmacro.h>
#include <mujoco/mujoco.h>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// A derived quantity the env reads after a call: an mjData field copied out by the batch, or
// sin/cos of qpos, evaluated in float64 before rounding (see COMPUTED_EXTRAS in Python), or a
// field that only mj_rnePostConstraint computes (POST_CONSTRAINT_EXTRAS in Python).
enum class ExtraKind { kOutput, kSinQpos, kCosQpos, kPostConstraint };

// An mjData array field, by name, as float64 values.
using DataGetter = const mjtNum* (*)(const mjData*);

struct Extra {
  std::string name;
  ExtraKind kind;
  int size;                     // values per simulation
  DataGetter get = nullptr;     // kOutput and kPostConstraint: the field in an mjData
};

// The mjData fields that mj_step leaves stale (MuJoCo computes them only for sensors that need
// them): gymnasium calls mj_rnePostConstraint after every step to get them, and never after a
// reset, where mj_resetData has zeroed them.
bool IsPostConstraint(const std::string& name) {
  return name == "cacc" || name == "cfrc_int" || name == "cfrc_ext";
}

DataGetter FindGetter(const std::string& name) {
#define X(type, field, nr, nc)                                              \
  if (name == #field) {                                                     \
    return [](const mjData* d) { return reinterpret_cast<const mjtNum*>(d->field); }; \
  }
  MJDATA_POINTERS
#undef X
  return nullptr;
}

enum class Operation { kStep, kForward };

// One mjBatch of nsim simulations and the addresses of the state components in its rows. It
// holds nothing a result depends on: every call writes the full physics state of every
// simulation before running it (as envs/mujoco/mujoco_backend._Workspace does).
struct Workspace {
  mjBatch* batch = nullptr;
  int nstate = 0;
  mjtNum* time = nullptr;
  mjtNum* qpos = nullptr;
  mjtNum* qvel = nullptr;
  mjtNum* warmstart = nullptr;
  mjtNum* ctrl = nullptr;
  mjWarningStat* warnings = nullptr;
  std::vector<const mjtNum*> outputs;  // per extra; nullptr for computed extras
  // With post-constraint extras a step runs through mjb_apply (StepWithPostConstraint), which
  // copies every field extra into these buffers itself (nsim x size each).
  std::vector<std::vector<mjtNum>> own_outputs;
  std::mutex mutex;                    // XLA may run two calls of one shape at once

  ~Workspace() {
    if (batch != nullptr) mjb_deleteBatch(batch);
  }
};

struct Context {
  mjModel* model = nullptr;
  int frame_skip = 1;
  int nthread = 1;
  std::vector<Extra> extras;
  bool post_constraint = false;  // some extra needs mj_rnePostConstraint after a step
  std::mutex mutex;  // guards workspaces
  std::map<std::pair<Operation, int64_t>, std::unique_ptr<Workspace>> workspaces;

  ~Context() {
    workspaces.clear();  // batches hold copies of the model, but free them first anyway
    if (model != nullptr) mj_deleteModel(model);
  }
};

std::mutex registry_mutex;
std::unordered_map<uint64_t, std::unique_ptr<Context>>& Registry() {
  // leaked on purpose: XLA may still run a call while the process exits
  static auto* registry = new std::unordered_map<uint64_t, std::unique_ptr<Context>>();
  return *registry;
}

Context* Find(uint64_t key) {
  std::lock_guard<std::mutex> lock(registry_mutex);
  auto found = Registry().find(key);
  return found == Registry().end() ? nullptr : found->second.get();
}

mjtNum* Component(mjBatch* batch, mjtState component) {
  return mjb_stateComponent(batch, static_cast<int>(component), nullptr);
}

// Workspace of (operation, nsim), made on first use; nullptr and a message on failure.
Workspace* GetWorkspace(Context* context, Operation operation, int64_t nsim, std::string* error) {
  std::lock_guard<std::mutex> lock(context->mutex);
  auto& slot = context->workspaces[{operation, nsim}];
  if (slot) return slot.get();
  mjBatchConfig config;
  mjb_defaultConfig(&config);
  config.nthread = context->nthread;
  char message[1000] = "";
  auto work = std::make_unique<Workspace>();
  work->batch = mjb_makeBatch(context->model, static_cast<int>(nsim), &config, message,
                              sizeof(message));
  if (work->batch == nullptr) {
    *error = std::string("mjb_makeBatch failed: ") + message;
    context->workspaces.erase({operation, nsim});
    return nullptr;
  }
  mjBatch* batch = work->batch;
  work->nstate = mjb_nstate(batch);
  work->time = Component(batch, mjSTATE_TIME);
  work->qpos = Component(batch, mjSTATE_QPOS);
  work->qvel = Component(batch, mjSTATE_QVEL);
  work->warmstart = Component(batch, mjSTATE_WARMSTART);
  work->ctrl = Component(batch, mjSTATE_CTRL);
  work->warnings = mjb_warning(batch);
  const bool own = operation == Operation::kStep && context->post_constraint;
  for (const Extra& extra : context->extras) {
    const void* output = nullptr;
    work->own_outputs.emplace_back(own && extra.get ? static_cast<size_t>(nsim) * extra.size : 0);
    if (own && extra.get != nullptr) {
      output = work->own_outputs.back().data();
    } else if (extra.kind == ExtraKind::kOutput) {
      output = mjb_output(batch, extra.name.c_str(), nullptr, nullptr);
    }
    work->outputs.push_back(static_cast<const mjtNum*>(output));
  }
  slot = std::move(work);
  return slot.get();
}

double LoadDouble(const uint32_t* words, int64_t index) {
  double value;
  std::memcpy(&value, words + 2 * index, sizeof(value));
  return value;
}

void StoreDouble(uint32_t* words, int64_t index, double value) {
  std::memcpy(words + 2 * index, &value, sizeof(value));
}

// Write every simulation's physics state (qpos, qvel, warm start) and controls into the rows;
// time and warning counters start from zero, as after mj_resetData.
void Load(Workspace* work, const mjModel* m, int64_t nsim, const uint32_t* state,
          const float* ctrl) {
  const int nq = m->nq, nv = m->nv, nu = m->nu, size = nq + 2 * nv;
  for (int64_t i = 0; i < nsim; ++i) {
    const int64_t row = i * work->nstate, first = i * size;
    work->time[row] = 0;
    for (int j = 0; j < nq; ++j) work->qpos[row + j] = LoadDouble(state, first + j);
    for (int j = 0; j < nv; ++j) work->qvel[row + j] = LoadDouble(state, first + nq + j);
    for (int j = 0; j < nv; ++j) {
      work->warmstart[row + j] = LoadDouble(state, first + nq + nv + j);
    }
    for (int j = 0; j < nu; ++j) work->ctrl[row + j] = ctrl ? ctrl[i * nu + j] : 0.0;
  }
  std::memset(work->warnings, 0, sizeof(mjWarningStat) * mjNWARNING * nsim);
}

bool Unstable(const mjWarningStat* warnings) {
  return warnings[mjWARN_BADQPOS].number > 0 || warnings[mjWARN_BADQVEL].number > 0 ||
         warnings[mjWARN_BADQACC].number > 0;
}

// NaN fails the comparison, so it counts as beyond the limit.
bool Beyond(const mjtNum* values, int n) {
  for (int j = 0; j < n; ++j) {
    if (!(std::fabs(values[j]) <= mjMAXVAL)) return true;
  }
  return false;
}

// mjb_apply's function for a step with post-constraint extras: gymnasium's do_simulation
// (frame_skip mj_steps, then mj_rnePostConstraint) and the field extras copied out of the
// simulation's mjData, since mjb_apply publishes no registered outputs.
struct PostConstraintStep {
  const Context* context;
  Workspace* work;
};

void StepWithPostConstraint(const mjModel* m, mjData* d, int sim, void* arg) {
  const auto* call = static_cast<const PostConstraintStep*>(arg);
  for (int k = 0; k < call->context->frame_skip; ++k) mj_step(m, d);
  mj_rnePostConstraint(m, d);
  for (size_t k = 0; k < call->context->extras.size(); ++k) {
    const Extra& extra = call->context->extras[k];
    if (extra.get == nullptr) continue;
    mjtNum* target = call->work->own_outputs[k].data() + static_cast<size_t>(sim) * extra.size;
    std::memcpy(target, extra.get(d), sizeof(mjtNum) * extra.size);
  }
}

struct Measured {  // the result buffers every call fills
  float* qpos;
  float* qvel;
  float* qpos_change;
  bool* diverged;
  std::vector<float*> extras;
};

// Results of a call, from the rows after it and the state before it.
void Measure(const Context& context, const Workspace& work, Operation operation, int64_t nsim,
             const uint32_t* state_before, uint32_t* state_after, const Measured& out) {
  const mjModel* m = context.model;
  const int nq = m->nq, nv = m->nv, size = nq + 2 * nv;
  for (int64_t i = 0; i < nsim; ++i) {
    const int64_t row = i * work.nstate;
    const mjtNum* qpos = work.qpos + row;
    const mjtNum* qvel = work.qvel + row;
    for (int j = 0; j < nq; ++j) {
      out.qpos[i * nq + j] = static_cast<float>(qpos[j]);
      out.qpos_change[i * nq + j] =
          static_cast<float>(qpos[j] - LoadDouble(state_before, i * size + j));
    }
    for (int j = 0; j < nv; ++j) out.qvel[i * nv + j] = static_cast<float>(qvel[j]);
    out.diverged[i] = Unstable(work.warnings + i * mjNWARNING) || Beyond(qpos, nq) ||
                      Beyond(qvel, nv);
    for (size_t k = 0; k < context.extras.size(); ++k) {
      const Extra& extra = context.extras[k];
      float* target = out.extras[k] + i * extra.size;
      for (int j = 0; j < extra.size; ++j) {
        double value;
        if (extra.kind == ExtraKind::kSinQpos) {
          value = std::sin(qpos[j]);
        } else if (extra.kind == ExtraKind::kCosQpos) {
          value = std::cos(qpos[j]);
        } else if (extra.kind == ExtraKind::kPostConstraint && operation == Operation::kForward) {
          value = 0.0;  // as after gymnasium's reset: mj_resetData zeroed it, mj_forward skips it
        } else {
          value = work.outputs[k][i * extra.size + j];
        }
        target[j] = static_cast<float>(value);
      }
    }
    if (state_after != nullptr) {
      for (int j = 0; j < nq; ++j) StoreDouble(state_after, i * size + j, qpos[j]);
      for (int j = 0; j < nv; ++j) StoreDouble(state_after, i * size + nq + j, qvel[j]);
      for (int j = 0; j < nv; ++j) {
        StoreDouble(state_after, i * size + nq + nv + j, work.warmstart[row + j]);
      }
    }
  }
}

uint64_t KeyOf(ffi::Buffer<ffi::U32> key) {
  const uint32_t* words = key.typed_data();
  return static_cast<uint64_t>(words[0]) | (static_cast<uint64_t>(words[1]) << 32);
}

ffi::Error CheckSize(const char* what, size_t actual, int64_t expected) {
  if (static_cast<int64_t>(actual) == expected) return ffi::Error::Success();
  return ffi::Error::InvalidArgument(std::string(what) + " has " + std::to_string(actual) +
                                     " elements, expected " + std::to_string(expected));
}

// Extra results, after the fixed ones, checked against the registered extras.
ffi::Error ExtraBuffers(const Context& context, int64_t nsim, ffi::RemainingRets rets,
                        std::vector<float*>* buffers) {
  if (rets.size() != context.extras.size()) {
    return ffi::Error::InvalidArgument("wrong number of extra results");
  }
  for (size_t k = 0; k < rets.size(); ++k) {
    auto buffer = rets.get<ffi::Buffer<ffi::F32>>(k);
    if (buffer.has_error()) return buffer.error();
    const Extra& extra = context.extras[k];
    ffi::Result<ffi::Buffer<ffi::F32>> result = buffer.value();
    ffi::Error error = CheckSize(extra.name.c_str(), result->element_count(),
                                 nsim * extra.size);
    if (error.failure()) return error;
    buffers->push_back(result->typed_data());
  }
  return ffi::Error::Success();
}

ffi::Error Failures(mjBatch* batch, int64_t nsim, int nfail) {
  const int* status = mjb_status(batch);
  for (int64_t i = 0; i < nsim; ++i) {
    if (status[i] != 0) {
      return ffi::Error::Internal("MuJoCo raised in " + std::to_string(nfail) +
                                  " simulations; simulation " + std::to_string(i) + ": " +
                                  mjb_error(batch, static_cast<int>(i)));
    }
  }
  return ffi::Error::Internal("MuJoCo raised in " + std::to_string(nfail) + " simulations");
}

// Shared by all operations: resolve the model, check shapes, run, measure. With ``active``
// (one flag per simulation) only the active simulations are stepped; the others keep their
// loaded state, so their state after is their state before, bit for bit, and their measured
// results describe that unchanged state (with stale extras: callers must not read them).
ffi::Error Run(Operation operation, ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::U32> state,
               const float* ctrl, size_t ctrl_count, const bool* active, size_t active_count,
               uint32_t* state_after, Measured out, ffi::RemainingRets extra_rets) {
  // An empty batch (zero envs) has nothing to step; its key operand is empty too under vmap.
  if (state.element_count() == 0 && key.element_count() == 0) return ffi::Error::Success();
  if (key.element_count() < 2) return ffi::Error::InvalidArgument("model key needs 2 words");
  Context* context = Find(KeyOf(key));
  if (context == nullptr) {
    return ffi::Error::InvalidArgument(
        "MuJoCo model key not registered in this process: build the env before running a "
        "program that steps it");
  }
  const mjModel* m = context->model;
  const int64_t size = m->nq + 2 * m->nv;
  const int64_t nsim = state.element_count() / (2 * size);
  ffi::Error error = CheckSize("state", state.element_count(), 2 * size * nsim);
  if (error.success() && ctrl != nullptr) error = CheckSize("ctrl", ctrl_count, nsim * m->nu);
  if (error.success() && active != nullptr) error = CheckSize("active", active_count, nsim);
  if (error.success()) error = ExtraBuffers(*context, nsim, extra_rets, &out.extras);
  if (error.failure() || nsim == 0) return error;

  std::string message;
  Workspace* work = GetWorkspace(context, operation, nsim, &message);
  if (work == nullptr) return ffi::Error::Internal(message);
  std::lock_guard<std::mutex> lock(work->mutex);
  Load(work, m, nsim, state.typed_data(), ctrl);
  int n = static_cast<int>(nsim);
  const int* ids = nullptr;
  std::vector<int> active_ids;
  if (active != nullptr) {
    for (int i = 0; i < n; ++i) {
      if (active[i]) active_ids.push_back(i);
    }
    ids = active_ids.data();
    n = static_cast<int>(active_ids.size());
  }
  int nfail = 0;
  if (n > 0) {
    if (operation == Operation::kForward) {
      nfail = mjb_forward(work->batch, ids, n, mjSTAGE_ACC);
    } else if (context->post_constraint) {
      PostConstraintStep call{context, work};
      nfail = mjb_apply(work->batch, ids, n, StepWithPostConstraint, &call, /*save=*/1);
    } else {
      nfail = mjb_step(work->batch, ids, n, context->frame_skip, mjSTAGE_NONE);
    }
  }
  if (nfail != 0) return Failures(work->batch, nsim, nfail);
  Measure(*context, *work, operation, nsim, state.typed_data(), state_after, out);
  return ffi::Error::Success();
}

ffi::Error StepImpl(ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::U32> state,
                    ffi::Buffer<ffi::F32> ctrl, ffi::ResultBuffer<ffi::U32> state_after,
                    ffi::ResultBuffer<ffi::F32> qpos, ffi::ResultBuffer<ffi::F32> qvel,
                    ffi::ResultBuffer<ffi::F32> qpos_change,
                    ffi::ResultBuffer<ffi::PRED> diverged, ffi::RemainingRets extras) {
  Measured out{qpos->typed_data(), qvel->typed_data(), qpos_change->typed_data(),
               diverged->typed_data(), {}};
  return Run(Operation::kStep, key, state, ctrl.typed_data(), ctrl.element_count(), nullptr, 0,
             state_after->typed_data(), std::move(out), extras);
}

// The step of the active simulations only (see Run): what a learner calls when the envs whose
// episode ended wait, frozen, for the others (REINFORCE's whole-episode batches).
ffi::Error StepActiveImpl(ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::U32> state,
                          ffi::Buffer<ffi::F32> ctrl, ffi::Buffer<ffi::PRED> active,
                          ffi::ResultBuffer<ffi::U32> state_after,
                          ffi::ResultBuffer<ffi::F32> qpos, ffi::ResultBuffer<ffi::F32> qvel,
                          ffi::ResultBuffer<ffi::F32> qpos_change,
                          ffi::ResultBuffer<ffi::PRED> diverged, ffi::RemainingRets extras) {
  Measured out{qpos->typed_data(), qvel->typed_data(), qpos_change->typed_data(),
               diverged->typed_data(), {}};
  return Run(Operation::kStep, key, state, ctrl.typed_data(), ctrl.element_count(),
             active.typed_data(), active.element_count(), state_after->typed_data(),
             std::move(out), extras);
}

ffi::Error ForwardImpl(ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::U32> state,
                       ffi::ResultBuffer<ffi::F32> qpos, ffi::ResultBuffer<ffi::F32> qvel,
                       ffi::ResultBuffer<ffi::F32> qpos_change,
                       ffi::ResultBuffer<ffi::PRED> diverged, ffi::RemainingRets extras) {
  Measured out{qpos->typed_data(), qvel->typed_data(), qpos_change->typed_data(),
               diverged->typed_data(), {}};
  return Run(Operation::kForward, key, state, nullptr, 0, nullptr, 0, nullptr, std::move(out),
             extras);
}

// Parse "name,name,..." into extras; false and a message if a name is unknown.
bool ParseExtras(const mjModel* m, const char* names, std::vector<Extra>* extras,
                 std::string* error) {
  char message[1000] = "";
  mjBatchConfig config;
  mjb_defaultConfig(&config);
  config.nthread = 1;
  mjBatch* probe = mjb_makeBatch(m, 1, &config, message, sizeof(message));
  if (probe == nullptr) {
    *error = std::string("mjb_makeBatch failed: ") + message;
    return false;
  }
  std::string list(names);
  bool ok = true;
  for (size_t start = 0; ok && start < list.size();) {
    size_t end = list.find(',', start);
    if (end == std::string::npos) end = list.size();
    std::string name = list.substr(start, end - start);
    start = end + 1;
    if (name == "sin_qpos" || name == "cos_qpos") {
      const ExtraKind kind = name[0] == 's' ? ExtraKind::kSinQpos : ExtraKind::kCosQpos;
      extras->push_back({name, kind, static_cast<int>(m->nq)});
      continue;
    }
    int size = 0, elemsize = 0;
    const DataGetter get = FindGetter(name);
    if (mjb_output(probe, name.c_str(), &size, &elemsize) == nullptr ||
        elemsize != sizeof(mjtNum) || get == nullptr) {
      *error = "not a floating-point mjData field the batch can copy out: " + name;
      ok = false;
    }
    const ExtraKind kind = IsPostConstraint(name) ? ExtraKind::kPostConstraint : ExtraKind::kOutput;
    extras->push_back({name, kind, size, get});
  }
  mjb_deleteBatch(probe);
  return ok;
}

}  // namespace

extern "C" {

// mjVERSION_HEADER of the headers this library was compiled against.
int rl_jax_mujoco_header_version(void) { return mjVERSION_HEADER; }

// mj_version() of the MuJoCo library this library runs with.
int rl_jax_mujoco_library_version(void) { return mj_version(); }

// Register a model (an MJB buffer, as mj_saveModel writes it) under key; 0 on success, else -1
// and a message in error. Registering a key again is a no-op: the key is a hash of everything
// passed here.
int rl_jax_mujoco_register(uint64_t key, const void* mjb, int64_t mjb_size, int frame_skip,
                           int nthread, const char* extras, char* error, int error_size) {
  std::lock_guard<std::mutex> lock(registry_mutex);
  if (Registry().count(key)) return 0;
  auto fail = [&](const std::string& message) {
    std::snprintf(error, error_size, "%s", message.c_str());
    return -1;
  };
  auto context = std::make_unique<Context>();
  context->model = mj_loadModelBuffer(mjb, mjb_size);
  if (context->model == nullptr) return fail("mj_loadModelBuffer could not load the model");
  const mjModel* m = context->model;
  if (frame_skip < 1 || nthread < 1) return fail("frame_skip and nthread must be >= 1");
  context->frame_skip = frame_skip;
  context->nthread = nthread;
  std::string message;
  if (!ParseExtras(m, extras, &context->extras, &message)) return fail(message);
  for (const Extra& extra : context->extras) {
    context->post_constraint |= extra.kind == ExtraKind::kPostConstraint;
  }
  Registry()[key] = std::move(context);
  return 0;
}

}  // extern "C"

namespace {

// The results of both step handlers, after their arguments.
template <typename Binding>
auto StepResults(Binding binding) {
  return std::move(binding)
      .template Ret<ffi::Buffer<ffi::U32>>()             // state after the step
      .template Ret<ffi::Buffer<ffi::F32>>()             // qpos
      .template Ret<ffi::Buffer<ffi::F32>>()             // qvel
      .template Ret<ffi::Buffer<ffi::F32>>()             // qpos change
      .template Ret<ffi::Buffer<ffi::PRED>>()            // diverged
      .RemainingRets();                                  // extras
}

// Model key, state (float64 bits) and ctrl: the arguments both step handlers start with.
auto StepArgs() {
  return ffi::Ffi::Bind()
      .Arg<ffi::Buffer<ffi::U32>>()   // model key
      .Arg<ffi::Buffer<ffi::U32>>()   // state, float64 bits
      .Arg<ffi::Buffer<ffi::F32>>();  // ctrl
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(RlJaxMujocoStep, StepImpl, StepResults(StepArgs()));

XLA_FFI_DEFINE_HANDLER_SYMBOL(RlJaxMujocoStepActive, StepActiveImpl,
                              StepResults(StepArgs().Arg<ffi::Buffer<ffi::PRED>>()));  // active

XLA_FFI_DEFINE_HANDLER_SYMBOL(RlJaxMujocoForward, ForwardImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::U32>>()  // model key
                                  .Arg<ffi::Buffer<ffi::U32>>()  // state, float64 bits
                                  .Ret<ffi::Buffer<ffi::F32>>()  // qpos
                                  .Ret<ffi::Buffer<ffi::F32>>()  // qvel
                                  .Ret<ffi::Buffer<ffi::F32>>()  // qpos change
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // diverged
                                  .RemainingRets());              // extras
