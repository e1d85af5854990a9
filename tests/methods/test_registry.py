from magbench.methods.registry import find_method, get_method, method_label


def test_method_label_is_the_registered_label():
    assert method_label("magical") == get_method("magical").label == "MAG.I.C.AL"
    assert find_method("magical") is get_method("magical")


def test_an_unregistered_name_is_its_own_label():
    assert find_method("no_such_method") is None
    assert method_label("no_such_method") == "no_such_method"
