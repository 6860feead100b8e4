defmodule ThinkingCap.Config.HostileFilesTest do
  # Description files from a hostile or careless hand: each is refused with
  # the file and a line, without running anything, without making atoms
  # beyond a small budget, and with a bounded number of errors. Not async:
  # the atom count it reads is the VM's, which other tests grow.
  use ExUnit.Case, async: false

  alias ThinkingCap.Config
  alias ThinkingCap.Config.Error

  @moduletag :tmp_dir
  @examples Path.expand("../../../../../priv/examples", __DIR__)

  defp write!(dir, name, content) do
    path = Path.join(dir, name)
    File.write!(path, content)
    path
  end

  defp refused!(path) do
    assert {:error, [%Error{} | _] = errors} = Config.read(path)
    assert length(errors) <= 51
    for e <- errors, do: assert(e.file == path)
    errors
  end

  test "invalid UTF-8 is refused at its line", %{tmp_dir: dir} do
    path = write!(dir, "bad.wdf", "[\n  name: \"caf\xE9\",\n]\n")
    assert [%Error{line: 2, message: message}] = refused!(path)
    assert message =~ "not UTF-8"
  end

  test "a file name with a NUL byte is refused at its line, not opened", %{tmp_dir: dir} do
    wdf = "[\n  name: \"x\",\n  map: [yaml: \"map.yaml\\0\"]\n]\n"
    assert [%Error{line: 3, message: message}] = refused!(write!(dir, "nul.wdf", wdf))
    assert message =~ "map.yaml: expected a file name"
    assert message =~ "without a NUL byte"

    adf = "[\n  robot: :r,\n  rdf: \"\",\n  modules: []\n]\n"
    assert [%Error{line: 3, message: message} | _] = refused!(write!(dir, "empty.adf", adf))
    assert message =~ "rdf: expected a file name"
  end

  test "unbalanced brackets and code are refused at their line", %{tmp_dir: dir} do
    assert [%Error{line: 3, message: "syntax error" <> message}] =
             refused!(write!(dir, "open.wdf", "[\n  name: \"x\", walls: [[{0, 0}, {1, 0}]\n"))

    assert message =~ "starting at line 2"

    assert [%Error{line: 1, message: message}] =
             refused!(write!(dir, "code.rdf", ~s|[name: File.rm_rf!("/")]|))

    assert message =~ "never evaluated"
  end

  test "deep nesting is refused before it is parsed", %{tmp_dir: dir} do
    deep = String.duplicate("[", 200_000) <> String.duplicate("]", 200_000)
    assert [%Error{line: 1, message: message}] = refused!(write!(dir, "deep.wdf", deep))
    assert message =~ "nested deeper than"
    # brackets inside strings and comments do not count
    flat = ~s|# [[[[[[\n[name: "#{String.duplicate("[", 100)}"]\n|
    assert {:ok, _} = Config.read(write!(dir, "flat.wdf", flat))
  end

  test "a file of many new names makes a bounded number of atoms", %{tmp_dir: dir} do
    # 300,000 distinct names never seen before
    prefix = "q#{:erlang.unique_integer([:positive])}x"
    names = Enum.map_join(1..300_000, ",", &":#{prefix}#{&1}")
    path = write!(dir, "atoms.wdf", "[name: \"x\", waypoints: [#{names}]]")
    before = :erlang.system_info(:atom_count)
    assert [%Error{message: message}] = refused!(path)
    assert message =~ "distinct new names"
    assert :erlang.system_info(:atom_count) - before <= 2_100

    # names that are not atom literals (variables) count in the same budget
    vars = Enum.map_join(1..300_000, ",", &"v#{prefix}#{&1}")
    before = :erlang.system_info(:atom_count)
    refused!(write!(dir, "vars.wdf", "[name: \"x\", waypoints: [#{vars}]]"))
    assert :erlang.system_info(:atom_count) - before <= 2_100
  end

  test "a huge file is refused by its size, unread", %{tmp_dir: dir} do
    path = Path.join(dir, "huge.wdf")
    {:ok, f} = :file.open(path, [:write, :raw])
    {:ok, _} = :file.position(f, 100_000_000)
    :ok = :file.write(f, "]")
    :ok = :file.close(f)
    assert [%Error{line: 0, message: message}] = refused!(path)
    assert message =~ "limited to"
  end

  test "many errors are cut at fifty, with a count of the rest", %{tmp_dir: dir} do
    keys = Enum.map_join(1..120, ", ", &"name#{&1}: 1")
    errors = refused!(write!(dir, "many.wdf", "[name: \"x\", #{keys}]"))
    assert length(errors) == 51
    assert List.last(errors).message =~ ~r/and \d+ more errors/
  end

  # random bytes and mutated real files: always an answer, never a crash
  test "fuzz: random bytes and mutated example files are answered, never crash", %{
    tmp_dir: dir
  } do
    sources =
      for f <- File.ls!(@examples),
          Path.extname(f) in ~w(.adf .rdf .wdf),
          do: {Path.extname(f), File.read!(Path.join(@examples, f))}

    gen =
      :proper_types.oneof([
        :proper_types.tuple([
          :proper_types.oneof([".adf", ".rdf", ".wdf"]),
          :proper_types.binary()
        ]),
        :proper_types.tuple([
          :proper_types.oneof(sources),
          :proper_types.list(
            :proper_types.tuple([:proper_types.float(0.0, 1.0), :proper_types.byte()])
          )
        ])
      ])

    property =
      :proper.forall(gen, fn input ->
        {ext, content} = mutate(input)
        path = write!(dir, "fuzz#{ext}", content)

        try do
          case Config.read(path) do
            {:ok, _} ->
              true

            # each error names the file read, or the map a WDF names (the
            # fleet example's, not beside the copy): after the WDF's own
            {:error, [first | _] = errors} ->
              length(errors) <= 51 and first.file == path and
                Enum.all?(errors, &(&1.file == path or Path.extname(&1.file) in ~w(.yaml .pgm)))
          end
        rescue
          # PropEr (as Debian ships it) cannot report an exception itself
          e -> flunk("#{inspect(content)} crashed the reader: #{Exception.message(e)}")
        end
      end)

    assert :proper.quickcheck(property, [
             {:numtests, 300},
             {:on_output, fn _format, _args -> :ok end},
             :long_result
           ]) == true
  end

  defp mutate({ext, bytes}) when is_binary(ext), do: {ext, bytes}

  defp mutate({{ext, source}, edits}) do
    {ext,
     Enum.reduce(edits, source, fn {at, byte}, s ->
       i = min(trunc(at * byte_size(s)), byte_size(s) - 1)
       <<head::binary-size(i), _, tail::binary>> = s
       <<head::binary, byte, tail::binary>>
     end)}
  end
end
