// nfal's own (not pythonfmu's): included by both patched runtimes' PySlaveInstance.cpp, built with their flags
// (Python's stable ABI). docs/cosimulation.md, "the value cache".
#pragma once

#include <Python.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <unordered_map>

namespace nfal
{

// The value cache of nfal's patched runtimes (fmus/runtime/, fmus/runtime3/). An nfal slave (fmus/base.py,
// NfalSlave._value_cache_layout) names its Real and Boolean inputs and outputs; the runtime keeps their values in a
// bytearray the slave holds a memoryview of (so it cannot move), and answers the gets and sets of every step from it
// without entering Python. Slot 0 is 1 while inputs set here wait for the slave, which takes them at the start of its
// next call; after a step it writes its state's outputs. Slot 1 is 1 while the outputs computed from the inputs
// (``depends_on``) are out of date (an input was set, the state stepped or was restored): a read of one then goes to
// Python, which computes and writes them all and clears it. A set value that is not finite, a value reference the
// layout does not name, or any other call goes to Python as before, so every error is the slave's own.
template<typename ValueReference>
class ValueCache
{
public:
    enum Role { input = 0, output = 1, computed = 2 };

    // With the GIL. The slave's layout, then its buffer bound; the cache stays off if the slave has none.
    void bind(PyObject* slave)
    {
        release();
        if (!PyObject_HasAttrString(slave, "_value_cache_layout")) {
            return;
        }
        PyObject* layout = PyObject_CallMethod(slave, "_value_cache_layout", nullptr);
        if (layout == nullptr || !PyList_Check(layout)) {
            Py_XDECREF(layout);
            PyErr_Clear();
            return;
        }
        const Py_ssize_t n = PyList_Size(layout);
        buffer_ = PyByteArray_FromStringAndSize(nullptr, (n + 2) * static_cast<Py_ssize_t>(sizeof(double)));
        if (buffer_ == nullptr) {
            Py_DECREF(layout);
            PyErr_Clear();
            return;
        }
        values_ = reinterpret_cast<double*>(PyByteArray_AsString(buffer_));
        std::fill(values_, values_ + n + 2, 0.0);
        for (Py_ssize_t i = 0; i < n; i++) {
            PyObject* item = PyList_GetItem(layout, i); // (value reference, is Boolean, role)
            const auto vr = static_cast<ValueReference>(PyLong_AsUnsignedLong(PyTuple_GetItem(item, 0)));
            const bool boolean = PyObject_IsTrue(PyTuple_GetItem(item, 1)) == 1;
            const auto role = static_cast<Role>(PyLong_AsLong(PyTuple_GetItem(item, 2)));
            (boolean ? booleans_ : reals_)[vr] = Slot{static_cast<std::size_t>(i) + 2, role};
            hasComputed_ = hasComputed_ || role == computed;
        }
        Py_DECREF(layout);
        PyObject* bound = PyErr_Occurred() != nullptr ? nullptr
                                                       : PyObject_CallMethod(slave, "_bind_value_cache", "(O)", buffer_);
        if (bound == nullptr) {
            PyErr_Clear();
            release();
            return;
        }
        Py_DECREF(bound);
        active_ = true;
    }

    // With the GIL: off, and the buffer let go.
    void release()
    {
        active_ = hasComputed_ = false;
        reals_.clear();
        booleans_.clear();
        values_ = nullptr;
        Py_CLEAR(buffer_);
    }

    // The values of vr[0..nvr) if the buffer holds them all, current.
    template<typename T>
    bool get(bool boolean, const ValueReference* vr, std::size_t nvr, T* values) const
    {
        if (!active_) {
            return false;
        }
        const auto& slots = boolean ? booleans_ : reals_;
        for (std::size_t i = 0; i < nvr; i++) {
            const auto slot = slots.find(vr[i]);
            if (slot == slots.end() || (slot->second.role == computed && values_[1] != 0.0)) {
                return false;
            }
            values[i] = static_cast<T>(values_[slot->second.index]);
        }
        return true;
    }

    // Whether vr[0..nvr) were set: all inputs of the buffer, all finite.
    template<typename T>
    bool set(bool boolean, const ValueReference* vr, std::size_t nvr, const T* values)
    {
        if (!active_) {
            return false;
        }
        const auto& slots = boolean ? booleans_ : reals_;
        for (std::size_t i = 0; i < nvr; i++) {
            const auto slot = slots.find(vr[i]);
            if (slot == slots.end() || slot->second.role != input || !std::isfinite(static_cast<double>(values[i]))) {
                return false;
            }
        }
        for (std::size_t i = 0; i < nvr; i++) {
            values_[slots.find(vr[i])->second.index] = boolean ? (values[i] ? 1.0 : 0.0) : static_cast<double>(values[i]);
        }
        values_[0] = 1.0; // inputs waiting for the slave
        stepped();
        return true;
    }

    // The computed outputs are out of date (an input was set, the state stepped or was restored).
    void stepped()
    {
        if (active_ && hasComputed_) {
            values_[1] = 1.0;
        }
    }

private:
    struct Slot
    {
        std::size_t index;
        Role role;
    };
    bool active_ = false;
    bool hasComputed_ = false;
    PyObject* buffer_ = nullptr; // the bytearray
    // its doubles: [0] 1 while inputs wait for the slave; [1] 1 while the computed outputs are out of date; then one
    // value per variable of the layout
    double* values_ = nullptr;
    std::unordered_map<ValueReference, Slot> reals_, booleans_;
};

} // namespace nfal
