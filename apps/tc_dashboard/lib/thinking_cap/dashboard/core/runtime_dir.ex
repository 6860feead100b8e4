defmodule ThinkingCap.Dashboard.Core.RuntimeDir do
  @moduledoc false
  # The dashboard's runtime files (yaws' logs): a directory of mode 0700 of
  # its own, under $XDG_RUNTIME_DIR when that is a private directory of
  # this user, else under the system's temporary directory, removed when
  # the dashboard stops. Nothing in it holds the token (access logging is
  # off), and no other user can read it anyway. A VM that halts without
  # stopping the dashboard leaves its directory behind: the next
  # dashboard removes those of this user whose VM is gone (`sweep/1`).

  @key {__MODULE__, :dir}

  @doc "The directory, made on first use."
  @spec path() :: Path.t()
  def path do
    case :persistent_term.get(@key, nil) do
      nil ->
        base = base()
        dir = Path.join(base, "thinkingcap-#{System.pid()}-#{random()}")
        File.mkdir_p!(dir)
        File.chmod!(dir, 0o700)
        :persistent_term.put(@key, dir)
        sweep(base)
        dir

      dir ->
        dir
    end
  end

  @doc "Removes the directory (and what is in it), if it was made."
  @spec remove() :: :ok
  def remove do
    case :persistent_term.get(@key, nil) do
      nil ->
        :ok

      dir ->
        File.rm_rf(dir)
        :persistent_term.erase(@key)
        :ok
    end
  end

  @doc """
  Removes the runtime directories under `base` that dashboards of VMs
  now gone left behind: named `thinkingcap-PID-...`, owned by this
  VM's user, and whose PID no process has. A directory whose PID was reused stays. Does nothing
  where the system has no `/proc` to ask. Returns the directories
  removed.
  """
  @spec sweep(Path.t()) :: [Path.t()]
  def sweep(base) do
    with true <- File.dir?("/proc"),
         {:ok, names} <- File.ls(base),
         {:ok, %{uid: uid}} <- File.stat("/proc/self") do
      for name <- names,
          [_, pid] <- [Regex.run(~r/^thinkingcap-(\d+)-[A-Za-z0-9_-]+$/, name)],
          not File.exists?("/proc/" <> pid),
          dir = Path.join(base, name),
          match?({:ok, %{type: :directory, uid: ^uid}}, File.lstat(dir)),
          match?({:ok, _}, File.rm_rf(dir)),
          do: dir
    else
      _ -> []
    end
  end

  defp base do
    case System.get_env("XDG_RUNTIME_DIR") do
      dir when is_binary(dir) and dir != "" ->
        if private?(dir), do: dir, else: System.tmp_dir!()

      _ ->
        System.tmp_dir!()
    end
  end

  defp private?(dir) do
    case File.stat(dir) do
      {:ok, %{type: :directory, mode: mode}} -> Bitwise.band(mode, 0o077) == 0
      _ -> false
    end
  end

  defp random, do: 6 |> :crypto.strong_rand_bytes() |> Base.url_encode64(padding: false)
end
