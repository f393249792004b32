#pragma once
// How many OpenMP threads a stage uses: the count asked for, or with 0 every
// core OpenMP offers (at least one). The result of every stage is the same
// for any count.
namespace pp5 {

int resolveThreads(int requested);

}  // namespace pp5
