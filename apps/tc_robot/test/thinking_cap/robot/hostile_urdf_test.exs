defmodule ThinkingCap.Robot.HostileURDFTest do
  # URDF files from a hostile or careless hand: each is read or refused
  # with the file and a line, never raises, reads no other file, makes no
  # atom. Not async: the atom count it reads is the VM's.
  use ExUnit.Case, async: false

  alias ThinkingCap.Config.Error
  alias ThinkingCap.Robot.URDF

  @moduletag :tmp_dir
  @turtlebot Path.expand("../../../../../test/data/turtlebot3_burger.urdf", __DIR__)

  defp write(dir, name, text) do
    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  defp refused(path) do
    assert {:error, [%Error{} | _] = errors} = URDF.load(path)
    assert length(errors) <= 51
    for e <- errors, do: assert(e.file == path)
    errors
  end

  test "a DOCTYPE is refused: no external entity is read, no entity expands", %{tmp_dir: dir} do
    secret = write(dir, "secret.txt", "SECRET")

    xxe = """
    <?xml version="1.0"?>
    <!DOCTYPE robot [<!ENTITY x SYSTEM "file://#{secret}">]>
    <robot name="&x;"><link name="l"/></robot>
    """

    assert [%Error{line: 2, message: message}] = refused(write(dir, "xxe.urdf", xxe))
    assert message =~ "a DOCTYPE"
    refute message =~ "SECRET"

    laughs =
      ~s(<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">) <>
        Enum.map_join(
          ?b..?k,
          "",
          &~s(<!ENTITY #{<<&1>>} "#{String.duplicate("&#{<<&1 - 1>>};", 10)}">)
        ) <>
        ~s(]><robot name="&k;"/>)

    assert [%Error{line: 1, message: "malformed XML: a DOCTYPE" <> _}] =
             refused(write(dir, "laughs.urdf", laughs))

    # an entity that is not XML's own is refused where it is used
    assert [%Error{line: 2, message: message}] =
             refused(write(dir, "ref.urdf", ~s(<robot name="r">\n<link name="&x;"/></robot>)))

    assert message =~ "an entity reference"

    # XML's own references are read
    path =
      write(
        dir,
        "own.urdf",
        ~s(<robot name="a&amp;b&#33;&#x3f;"><link name="&lt;l&gt;"/></robot>)
      )

    assert {:ok, %URDF{name: "a&b!?", links: %{"<l>" => _}}} = URDF.load(path)
  end

  test "deep nesting and many elements are refused at their line", %{tmp_dir: dir} do
    deep =
      "<robot>\n" <>
        String.duplicate("<a>", 200_000) <> String.duplicate("</a>", 200_000) <> "</robot>"

    assert [%Error{line: 2, message: message}] = refused(write(dir, "deep.urdf", deep))
    assert message == "malformed XML: elements nested deeper than 64"

    many = "<robot>\n" <> String.duplicate("<a/>\n", 100_001) <> "</robot>"
    assert [%Error{line: 100_001, message: message}] = refused(write(dir, "many.urdf", many))
    assert message == "malformed XML: more than 100000 elements"
  end

  # checked per link up to the root, a long arm took minutes (quadratic);
  # the default test timeout (60 s) bounds it now
  test "a long arm of 10,000 links is read, and a loop in it found", %{tmp_dir: dir} do
    joints =
      Enum.map_join(1..9_999, "\n", fn i ->
        ~s(<link name="l#{i}"/><joint name="j#{i}" type="fixed">) <>
          ~s(<parent link="l#{i - 1}"/><child link="l#{i}"/></joint>)
      end)

    path = write(dir, "arm.urdf", ~s(<robot name="arm">\n<link name="l0"/>\n#{joints}\n</robot>))
    assert {:ok, %URDF{links: links}} = URDF.load(path)
    assert map_size(links) == 10_000

    loop = ~s(<joint name="back" type="fixed"><parent link="l9999"/><child link="l0"/></joint>)

    path =
      write(
        dir,
        "loop.urdf",
        ~s(<robot name="arm">\n<link name="l0"/>\n#{joints}\n#{loop}</robot>)
      )

    assert [%Error{message: "the joints form a loop through link \"l0\""}] = refused(path)
  end

  test "a file of novel tag and attribute names makes no atom", %{tmp_dir: dir} do
    prefix = "zq#{:erlang.unique_integer([:positive])}"

    body =
      Enum.map_join(1..20_000, "\n", &~s(<#{prefix}t#{&1} #{prefix}a#{&1}="#{prefix}v#{&1}"/>))

    path = write(dir, "atoms.urdf", ~s(<robot name="r"><link name="l"/>#{body}</robot>))
    # the reader's code loaded first: loading a module makes atoms
    {:ok, _} = URDF.load(@turtlebot)
    refused(write(dir, "warm.urdf", "<robot><link/></robot>"))
    before = :erlang.system_info(:atom_count)
    assert {:ok, %URDF{}} = URDF.load(path)
    # other processes of the VM may make a few atoms meanwhile; the file's
    # names (thousands) are not among them
    assert :erlang.system_info(:atom_count) - before < 200

    for name <- ["#{prefix}t1", "#{prefix}a1", "#{prefix}v1", "#{prefix}k1", "#{prefix}mode"],
        do: assert_raise(ArgumentError, fn -> String.to_existing_atom(name) end)
  end

  test "a huge file, invalid UTF-8, not a file", %{tmp_dir: dir} do
    path = Path.join(dir, "huge.urdf")
    {:ok, f} = :file.open(path, [:write, :raw])
    {:ok, _} = :file.position(f, 100_000_000)
    :ok = :file.write(f, ">")
    :ok = :file.close(f)
    assert [%Error{line: 0, message: message}] = refused(path)
    assert message == "100000001 bytes: a URDF is limited to 4194304 bytes"

    path = write(dir, "latin1.urdf", "<robot>\n<link name=\"caf\xE9\"/></robot>")

    assert [%Error{line: 2, column: 16, message: "not UTF-8 text: invalid bytes here"}] =
             refused(path)

    assert [%Error{message: "the URDF is not a regular file (directory)"}] = refused(dir)
  end

  test "many errors are cut at fifty, with a count of the rest", %{tmp_dir: dir} do
    path =
      write(dir, "many.urdf", "<robot>\n" <> String.duplicate("<link/>\n", 120) <> "</robot>")

    errors = refused(path)
    assert length(errors) == 51
    assert List.last(errors).message == "and 70 more errors"
  end

  test "fuzz: random bytes and mutated URDFs are answered, never raise", %{tmp_dir: dir} do
    source = File.read!(@turtlebot)

    gen =
      :proper_types.oneof([
        :proper_types.binary(),
        # random bytes inside a robot element
        :proper_types.tuple([:inside, :proper_types.binary()]),
        # the TurtleBot's URDF with bytes changed, or cut
        :proper_types.tuple([
          :proper_types.list(
            :proper_types.tuple([:proper_types.float(0.0, 1.0), :proper_types.byte()])
          ),
          :proper_types.float(0.0, 1.0)
        ])
      ])

    path = Path.join(dir, "fuzz.urdf")

    property =
      :proper.forall(gen, fn input ->
        File.write!(path, content(input, source))

        try do
          case URDF.load(path) do
            {:ok, %URDF{}} ->
              true

            {:error, [_ | _] = errors} ->
              length(errors) <= 51 and
                Enum.all?(errors, &(&1.file == path and is_integer(&1.line)))
          end
        rescue
          # PropEr (as Debian ships it) cannot report an exception itself
          e -> flunk("#{inspect(input)} raised: #{Exception.message(e)}")
        end
      end)

    assert :proper.quickcheck(property, [
             {:numtests, 300},
             {:on_output, fn _format, _args -> :ok end},
             :long_result
           ]) == true
  end

  defp content(bytes, _source) when is_binary(bytes), do: bytes
  defp content({:inside, bytes}, _source), do: "<robot name=\"r\">" <> bytes <> "</robot>"

  defp content({edits, cut}, source) do
    mutated =
      Enum.reduce(edits, source, fn {at, byte}, s ->
        i = min(trunc(at * byte_size(s)), byte_size(s) - 1)
        <<head::binary-size(i), _, tail::binary>> = s
        <<head::binary, byte, tail::binary>>
      end)

    if cut > 0.9,
      do: binary_part(mutated, 0, trunc((cut - 0.9) * 10 * byte_size(mutated))),
      else: mutated
  end
end
