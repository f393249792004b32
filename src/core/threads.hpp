#pragma once
// How many OpenMP threads a stage uses: the count asked for, or with 0 every
// core OpenMP offers (at least one). The result of every stage is the same
// for any count.
namespace pp5 {

// The most threads any setting or option may ask for (more is a typo: each
// thread costs its scratch memory and its start).
inline constexpr int kMaxThreads = 1024;

int resolveThreads(int requested);

}  // namespace pp5
