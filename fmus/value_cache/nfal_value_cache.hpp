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
// layout does not name, or any other call goes to Python as before, so every error is the slave's own. A slave may
// also have a compiled core (NfalSlave._value_cache_core): a C function that takes a doStep on the buffer and says
// whether it did (slot 2 then says the state's outputs and the time, slot 3, are newer than the slave's, which takes
// them at its next call); a step it declines goes to Python, which does it all. Slot 4 is 1 while the slave holds
// every step for its Python (not initialised: a state restored from before initialisation ended), whatever its core.
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
        buffer_ = PyByteArray_FromStringAndSize(nullptr, (n + kFirstSlot) * static_cast<Py_ssize_t>(sizeof(double)));
        if (buffer_ == nullptr) {
            Py_DECREF(layout);
            PyErr_Clear();
            return;
        }
        values_ = reinterpret_cast<double*>(PyByteArray_AsString(buffer_));
        size_ = static_cast<std::size_t>(n) + kFirstSlot;
        std::fill(values_, values_ + size_, 0.0);
        for (Py_ssize_t i = 0; i < n; i++) {
            PyObject* item = PyList_GetItem(layout, i); // (value reference, is Boolean, role)
            const auto vr = static_cast<ValueReference>(PyLong_AsUnsignedLong(PyTuple_GetItem(item, 0)));
            const bool boolean = PyObject_IsTrue(PyTuple_GetItem(item, 1)) == 1;
            const auto role = static_cast<Role>(PyLong_AsLong(PyTuple_GetItem(item, 2)));
            (boolean ? booleans_ : reals_)[vr] = Slot{static_cast<std::size_t>(i) + kFirstSlot, role};
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
        bindCore(slave);
    }

    // With the GIL: off, and the buffer let go.
    void release()
    {
        active_ = hasComputed_ = false;
        reals_.clear();
        booleans_.clear();
        values_ = nullptr;
        size_ = 0;
        core_ = nullptr;
        Py_CLEAR(buffer_);
        Py_CLEAR(coreData_);
    }

    // A doStep by the slave's compiled core, if it has one and takes this step; false: the slave's Python steps.
    bool step(double t, double dt)
    {
        if (!active_ || core_ == nullptr || values_[kCoreHeld] != 0.0 ||
            core_(values_, size_, coreValues_, coreSize_, t, dt) != 0) {
            return false;
        }
        values_[kCoreStepped] = 1.0; // the state's outputs and the time are the buffer's
        stepped();
        return true;
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
            if (slot == slots.end() || (slot->second.role == computed && values_[kComputedStale] != 0.0)) {
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
        values_[kInputsWaiting] = 1.0;
        stepped();
        return true;
    }

    // The computed outputs are out of date (an input was set, the state stepped or was restored).
    void stepped()
    {
        if (active_ && hasComputed_) {
            values_[kComputedStale] = 1.0;
        }
    }

private:
    // int core(double* values, size_t n_values, double* data, size_t n_data, double t, double dt): 0 stepped, else
    // left to the slave (models/plant_core.py).
    using Core = int (*)(double*, std::size_t, double*, std::size_t, double, double);

    // With the GIL: the slave's (address, data address, data size, data owner), or None.
    void bindCore(PyObject* slave)
    {
        if (!PyObject_HasAttrString(slave, "_value_cache_core")) {
            return;
        }
        PyObject* core = PyObject_CallMethod(slave, "_value_cache_core", nullptr);
        if (core != nullptr && PyTuple_Check(core) && PyTuple_Size(core) == 4) {
            core_ = reinterpret_cast<Core>(PyLong_AsVoidPtr(PyTuple_GetItem(core, 0)));
            coreValues_ = static_cast<double*>(PyLong_AsVoidPtr(PyTuple_GetItem(core, 1)));
            coreSize_ = static_cast<std::size_t>(PyLong_AsSize_t(PyTuple_GetItem(core, 2)));
            coreData_ = PyTuple_GetItem(core, 3);
            Py_INCREF(coreData_);
        }
        Py_XDECREF(core);
        if (PyErr_Occurred() != nullptr) {
            PyErr_Clear();
            core_ = nullptr;
            Py_CLEAR(coreData_);
        }
    }

    struct Slot
    {
        std::size_t index;
        Role role;
    };
    // The buffer's doubles (fmus/base.py names them alike): 1 while inputs wait for the slave; 1 while the computed
    // outputs are out of date; 1 while the state's outputs and the time (the next slot) are newer than the slave's
    // (its core stepped); the time; 1 while the slave holds its steps from its core; then one value per variable of
    // the layout.
    static constexpr std::size_t kInputsWaiting = 0, kComputedStale = 1, kCoreStepped = 2, kCoreHeld = 4;
    static constexpr Py_ssize_t kFirstSlot = 5;
    bool active_ = false;
    bool hasComputed_ = false;
    PyObject* buffer_ = nullptr; // the bytearray
    double* values_ = nullptr;
    std::size_t size_ = 0;
    Core core_ = nullptr;
    PyObject* coreData_ = nullptr; // what owns the core's data
    double* coreValues_ = nullptr;
    std::size_t coreSize_ = 0;
    std::unordered_map<ValueReference, Slot> reals_, booleans_;
};

} // namespace nfal
